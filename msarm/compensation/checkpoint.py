"""The trained compensator: weights, normalizers, config and metadata, saved and loaded safely.

A :class:`Compensator` maps features ``x`` (shape ``(d,)`` or ``(N, d)``) to predicted
joint-torque errors ``y`` [N·m] (shape ``(n,)`` or ``(N, n)``) with the network of
:mod:`msarm.compensation.network`. Its ``metadata`` dict says what it was made for; the keys
msarm itself reads are:

- ``"model_sha256"``: SHA-256 (hex) of the robot model file the training data came from;
- ``"feature_spec"``: the feature specification (a plain dict) that turns observations into
  ``x``.

A compensator file is written with ``torch.save`` and holds only plain containers (dicts,
lists, tuples, strings, numbers, tensors), so :meth:`Compensator.load` reads it with
``torch.load(weights_only=True)``: loading never unpickles arbitrary classes. Loading refuses,
with a :class:`CheckpointError` saying why, a file that is missing, corrupt, of another format
or version, or missing keys, and, when asked, a compensator made for another robot model (both
hashes shown) or another feature spec (the differing keys shown).
"""

from __future__ import annotations

import hashlib
import json
import pickle
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from msarm.compensation.features import FeatureSpec
from msarm.compensation.network import (
    DTYPE,
    TRAINING_CHECKPOINT_FORMAT,
    NetworkConfig,
    Normalizer,
    _atomic_torch_save,
    _plain_copy,
    as_feature_array,
    build_mlp,
    check_finite,
)
from msarm.errors import ConfigError, InputError, MsarmError
from msarm.io.config import (
    MISSING,
    config_to_dict,
    folder_instead_of_file,
    join_differences,
    load_config,
    value_differences,
)

__all__ = ["COMPENSATOR_FORMAT", "COMPENSATOR_VERSION", "CheckpointError", "Compensator"]

FloatArray = NDArray[np.float64]

#: Format tag and version of a compensator file.
COMPENSATOR_FORMAT = "msarm.compensation.compensator"
COMPENSATOR_VERSION = 1
_KEYS = (
    "format",
    "format_version",
    "input_dim",
    "output_dim",
    "config",
    "state_dict",
    "input_normalizer",
    "output_normalizer",
    "metadata",
)
#: What a compensator file is, for the error messages of files that are not one.
_EXPECTED = (
    "the compensator checkpoint file that msarm train writes (Compensator.save), by default "
    "runs/compensator/compensator.pt"
)
#: Most differences listed when a feature spec does not match.
_MAX_DIFFERENCES = 10


class CheckpointError(MsarmError):
    """A compensator or training checkpoint cannot be used: the message says why."""


class Compensator:
    """A trained feedforward compensator: features in, joint-torque errors [N·m] out.

    Attributes:
        config: The network shape and the training settings it was trained with.
        input_normalizer: Normalizer of the ``d`` inputs (fitted on the training inputs).
        output_normalizer: Normalizer of the ``n`` outputs (fitted on the training targets).
        metadata: What the compensator was made for (plain data; see the module docstring),
            filled by the caller; saved and loaded with it.
    """

    def __init__(
        self,
        state_dict: Mapping[str, torch.Tensor],
        input_normalizer: Normalizer,
        output_normalizer: Normalizer,
        config: NetworkConfig,
        metadata: Mapping[str, Any] | None = None,
    ) -> None:
        """Build the compensator from network weights.

        Args:
            state_dict: Weights of ``build_mlp(d, n, config)`` (its ``state_dict()``), where
                ``d`` and ``n`` are the normalizers' sizes; copied (as float64).
            input_normalizer: Normalizer of the inputs, size ``d``.
            output_normalizer: Normalizer of the outputs, size ``n``.
            config: Network config (hidden widths, activation, training settings).
            metadata: Plain data describing what the compensator is for (copied).

        Raises:
            InputError: The weights do not fit that network, or metadata is not plain data.
        """
        if not isinstance(config, NetworkConfig):
            raise InputError(f"config must be a NetworkConfig, got {type(config).__name__}")
        if not isinstance(input_normalizer, Normalizer) or not isinstance(
            output_normalizer, Normalizer
        ):
            raise InputError("input_normalizer and output_normalizer must be Normalizer objects")
        self.config = config
        self.input_normalizer = input_normalizer
        self.output_normalizer = output_normalizer
        d, n = input_normalizer.size, output_normalizer.size
        with torch.random.fork_rng(devices=[]):  # the initial weights are overwritten below
            module = build_mlp(d, n, config)
        try:
            module.load_state_dict(dict(state_dict), strict=True)
        except (RuntimeError, KeyError, TypeError) as exc:
            raise InputError(
                f"the weights do not fit a network {d} -> {list(config.hidden)} -> {n} "
                f"({config.activation}): {exc}"
            ) from None
        module.eval()
        module.requires_grad_(False)
        self._module = module
        self.metadata: dict[str, Any] = _plain_copy(dict(metadata or {}), "metadata")

    # --- shape and weights ----------------------------------------------------------------

    @property
    def input_dim(self) -> int:
        """Number of inputs ``d``."""
        return self.input_normalizer.size

    @property
    def output_dim(self) -> int:
        """Number of outputs ``n``."""
        return self.output_normalizer.size

    def state_dict(self) -> dict[str, torch.Tensor]:
        """A copy of the network weights (float64 tensors, torch ``state_dict`` names).

        Returns:
            ``{"0.weight": (h1, d), "0.bias": (h1,), ...}``: each linear layer's weight
            ``(out, in)`` and bias ``(out,)``, in normalised units, detached clones.
        """
        return {k: v.detach().clone() for k, v in self._module.state_dict().items()}

    def layer_weights(self) -> list[tuple[FloatArray, FloatArray]]:
        """The weights of each linear layer, input side first, as float64 numpy copies.

        Returns:
            ``[(W, b), ...]`` with ``W`` of shape ``(out, in)`` and ``b`` of shape ``(out,)``,
            acting on normalised units: ``z_next = act(W @ z + b)`` (no activation on the
            last layer).
        """
        return [
            (
                np.ascontiguousarray(layer.weight.detach().numpy(), dtype=np.float64).copy(),
                np.ascontiguousarray(layer.bias.detach().numpy(), dtype=np.float64).copy(),
            )
            for layer in self._module
            if isinstance(layer, torch.nn.Linear)
        ]

    # --- inference ------------------------------------------------------------------------

    def predict(self, x: ArrayLike) -> FloatArray:
        """Predict the joint-torque errors with torch.

        Args:
            x: Features, shape ``(d,)`` for one sample or ``(N, d)`` for a batch; finite.

        Returns:
            Predicted targets [N·m], shape ``(n,)`` or ``(N, n)`` (float64).

        Raises:
            InputError: Wrong shape (a ragged sequence too), or a NaN/inf (row and column
                named).
        """
        array = as_feature_array(x, f"({self.input_dim},) or (N, {self.input_dim})")
        if array.ndim not in (1, 2) or array.shape[-1] != self.input_dim:
            raise InputError(
                f"Compensator.predict expects shape ({self.input_dim},) or (N, "
                f"{self.input_dim}), got {array.shape}"
            )
        single = array.ndim == 1
        batch = array.reshape(1, -1) if single else array
        check_finite("x", batch)
        z = torch.from_numpy(np.ascontiguousarray(self.input_normalizer.normalize(batch)))
        with torch.inference_mode():
            out = self._module(z.to(DTYPE)).numpy()
        y = self.output_normalizer.denormalize(out)
        return y[0] if single else y

    __call__ = predict

    # --- files ----------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The plain form written by :meth:`save` (tensors, dicts, lists, strings, numbers).

        Returns:
            A dict with ``format``, ``format_version``, ``input_dim``, ``output_dim``,
            ``config`` (plain data), ``state_dict`` (see :meth:`state_dict`),
            ``input_normalizer`` and ``output_normalizer`` (see :meth:`Normalizer.to_dict`)
            and ``metadata``; :meth:`from_dict` reads it back.

        Raises:
            InputError: ``metadata`` holds something that is not plain data (key named).
        """
        return {
            "format": COMPENSATOR_FORMAT,
            "format_version": COMPENSATOR_VERSION,
            "input_dim": self.input_dim,
            "output_dim": self.output_dim,
            "config": config_to_dict(self.config),
            "state_dict": self.state_dict(),
            "input_normalizer": self.input_normalizer.to_dict(),
            "output_normalizer": self.output_normalizer.to_dict(),
            "metadata": _plain_copy(self.metadata, "metadata"),
        }

    def behaviour_sha256(self) -> str:
        """SHA-256 (hex) of everything that decides what this compensator does in a run.

        The weights, normalisers, network config and metadata (the robot model, feature and
        target specs, the recipe with its controller gains, the sheath stage), but not the
        training's own record (``metadata["training"]``: losses, epochs, times) nor where the
        recipe put its files (its ``checkpoint`` and ``data.folder``). Two trainings that end
        in the same network thus have the same value, though their files differ in their
        recorded times or places; ``msarm compare`` keys its runs with feedforward by it, so that
        a retraining that changed nothing does not make it simulate them again.

        Returns:
            64 hex digits.
        """
        plain = self.to_dict()
        metadata = {k: v for k, v in plain["metadata"].items() if k != "training"}
        recipe = metadata.get("recipe")
        if isinstance(recipe, Mapping):  # where its files went changes nothing it does
            recipe = {k: v for k, v in recipe.items() if k != "checkpoint"}
            if isinstance(recipe.get("data"), Mapping):
                recipe["data"] = {k: v for k, v in recipe["data"].items() if k != "folder"}
            metadata["recipe"] = recipe
        plain["metadata"] = metadata
        text = json.dumps(plain, sort_keys=True, default=_hashable)
        return hashlib.sha256(text.encode()).hexdigest()

    def save(self, path: str | Path) -> Path:
        """Write the compensator atomically (temporary file in the same folder, then rename).

        Args:
            path: Destination file (conventionally ``*.pt``); its folder is created if missing.

        Returns:
            The path written.

        Raises:
            InputError: ``metadata`` holds something that is not plain data (key named).
        """
        path = Path(path)
        _atomic_torch_save(self.to_dict(), path)
        return path

    @classmethod
    def load(
        cls,
        path: str | Path,
        expected_model_sha256: str | None = None,
        expected_feature_spec: FeatureSpec | Mapping[str, Any] | None = None,
    ) -> Compensator:
        """Read a compensator written by :meth:`save`, refusing one that does not fit.

        Args:
            path: The compensator file.
            expected_model_sha256: If given, the SHA-256 of the robot model in use: the file
                must have been made for it (``metadata["model_sha256"]``).
            expected_feature_spec: If given, the feature spec in use (a
                :class:`~msarm.compensation.features.FeatureSpec`, or a plain dict such as
                its :meth:`~msarm.compensation.features.FeatureSpec.as_dict`): the file's
                ``metadata["feature_spec"]`` must equal its dict form (tuples and lists
                compare equal).

        Returns:
            The compensator.

        Raises:
            InputError: ``expected_feature_spec`` is neither a FeatureSpec nor a mapping.
            CheckpointError: The file is missing, unreadable or corrupt, not a compensator
                file, of another format version, or lacks keys; or it was made for another
                robot model or another feature spec. The message says which, and shows the
                values that differ.
        """
        expected_feature_spec = _feature_spec_dict(expected_feature_spec)
        path = Path(path)
        if not path.is_file():
            folder = folder_instead_of_file(path, _EXPECTED)
            raise CheckpointError(
                folder
                or f"{path}: compensator file not found; expected {_EXPECTED} (run "
                "`msarm train`, or `make demo`, to make one)"
            )
        if not zipfile.is_zipfile(path):  # torch.save writes a zip archive
            raise CheckpointError(
                f"{path}: not a readable compensator file (not the zip archive that "
                "Compensator.save writes: corrupt, truncated, or another kind of file); "
                f"expected {_EXPECTED}"
            )
        try:
            saved = torch.load(path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as exc:
            if "weights only" not in str(exc).lower():
                raise CheckpointError(
                    f"{path}: not a readable compensator file (a torch file whose contents "
                    "cannot be read: corrupt or truncated), so it is not a usable msarm "
                    f"compensator checkpoint; expected {_EXPECTED}"
                ) from None
            # objects that weights_only refuses to build: not what Compensator.save writes
            raise CheckpointError(
                f"{path}: not a readable compensator file: it holds objects other than plain "
                "data (refused without unpickling them), so it is not an msarm compensator "
                f"checkpoint; expected {_EXPECTED}"
            ) from None
        except Exception:  # a zip that torch cannot read: its reason is about torch's internals
            raise CheckpointError(
                f"{path}: not a readable compensator file (a zip archive, but not one that "
                "torch.save wrote in full: another kind of zip file, or a corrupt one), so it is "
                f"not an msarm compensator checkpoint; expected {_EXPECTED}"
            ) from None
        compensator = cls.from_dict(saved, source=str(path))
        compensator.check_compatible(expected_model_sha256, expected_feature_spec, str(path))
        return compensator

    @classmethod
    def from_dict(cls, saved: Any, source: str = "<dict>") -> Compensator:
        """Build a compensator from the plain form of :meth:`to_dict`.

        Args:
            saved: The plain form.
            source: Where it came from, for error messages.

        Returns:
            The compensator (not yet checked against a model or a feature spec).

        Raises:
            CheckpointError: Wrong format or version, missing keys, or contents that do not fit.
        """
        if not isinstance(saved, Mapping):
            raise CheckpointError(
                f"{source}: not an msarm compensator checkpoint (holds a "
                f"{type(saved).__name__}, not the dict Compensator.save writes); expected "
                f"{_EXPECTED}"
            )
        fmt = saved.get("format")
        if fmt == TRAINING_CHECKPOINT_FORMAT:
            raise CheckpointError(
                f"{source}: this is a training checkpoint (what an interrupted training "
                "resumes from), not a compensator; give the compensator that msarm train "
                "wrote (the recipe's checkpoint, by default runs/compensator/compensator.pt)"
            )
        if fmt != COMPENSATOR_FORMAT:
            keys = ", ".join(repr(k) for k in list(saved)[:5]) + (", ..." if len(saved) > 5 else "")
            tag = (
                "no 'format' tag"
                if fmt is None
                else f"the format tag {fmt!r}, not {COMPENSATOR_FORMAT!r}"
            )
            raise CheckpointError(
                f"{source}: not an msarm compensator checkpoint (a dict with {tag}; its keys: "
                f"{keys or 'none'}); expected {_EXPECTED}"
            )
        version = saved.get("format_version")
        if version != COMPENSATOR_VERSION:
            raise CheckpointError(
                f"{source}: compensator format version {version!r}; this msarm reads version "
                f"{COMPENSATOR_VERSION}"
            )
        missing = [k for k in _KEYS if k not in saved]
        if missing:
            raise CheckpointError(
                f"{source}: compensator file is missing keys: {', '.join(missing)}"
            )
        try:
            config = load_config(saved["config"], NetworkConfig)
        except ConfigError as exc:
            raise CheckpointError(f"{source}: invalid network config: {exc}") from None
        try:
            in_norm = Normalizer.from_dict(saved["input_normalizer"])
            out_norm = Normalizer.from_dict(saved["output_normalizer"])
        except (InputError, KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f"{source}: invalid normalizer: {exc}") from None
        if (in_norm.size, out_norm.size) != (saved["input_dim"], saved["output_dim"]):
            raise CheckpointError(
                f"{source}: normalizers have {in_norm.size} inputs and {out_norm.size} outputs, "
                f"the file says {saved['input_dim']} and {saved['output_dim']}"
            )
        if not isinstance(saved["metadata"], Mapping):
            raise CheckpointError(
                f"{source}: metadata must be a dict, got {type(saved['metadata']).__name__}"
            )
        if not isinstance(saved["state_dict"], Mapping):
            raise CheckpointError(f"{source}: state_dict must be a dict of tensors")
        for name, tensor in saved["state_dict"].items():
            if isinstance(tensor, torch.Tensor) and not bool(torch.isfinite(tensor).all()):
                bad = int((~torch.isfinite(tensor)).sum())
                raise CheckpointError(
                    f"{source}: the network's weights {name!r} hold {bad} value(s) that are "
                    "not finite (NaN or infinite); a corrupt or diverged compensator, expected "
                    "finite weights: train it again"
                )
        try:
            return cls(saved["state_dict"], in_norm, out_norm, config, saved["metadata"])
        except InputError as exc:
            raise CheckpointError(f"{source}: {exc}") from None

    def check_compatible(
        self,
        expected_model_sha256: str | None = None,
        expected_feature_spec: FeatureSpec | Mapping[str, Any] | None = None,
        source: str = "compensator",
    ) -> None:
        """Refuse a compensator made for another robot model or another feature spec.

        Args:
            expected_model_sha256: SHA-256 (hex) of the robot model in use, or None to skip.
            expected_feature_spec: The feature spec in use (a
                :class:`~msarm.compensation.features.FeatureSpec` or a plain dict of its
                fields), or None to skip.
            source: Name of the compensator in messages (its file).

        Raises:
            InputError: ``expected_feature_spec`` is neither a FeatureSpec nor a mapping.
            CheckpointError: The metadata lacks the key, or records another value (both
                shown; for a feature spec, each differing key with both values).
        """
        expected_feature_spec = _feature_spec_dict(expected_feature_spec)
        if expected_model_sha256 is not None:
            recorded = self.metadata.get("model_sha256")
            if recorded is None:
                raise CheckpointError(
                    f"{source}: records no robot model (metadata has no 'model_sha256'); "
                    f"expected a compensator made for model {expected_model_sha256}"
                )
            if str(recorded).lower() != str(expected_model_sha256).lower():
                raise CheckpointError(
                    f"{source}: made for another robot model: its model SHA-256 is {recorded}, "
                    f"the model in use has {expected_model_sha256}; retrain it for this model"
                )
        if expected_feature_spec is not None:
            if "feature_spec" not in self.metadata:
                raise CheckpointError(
                    f"{source}: records no feature spec (metadata has no 'feature_spec')"
                )
            expected = _comparable(_plain_copy(dict(expected_feature_spec), "feature_spec"))
            recorded = _comparable(self.metadata["feature_spec"])
            diffs = _differences(recorded, expected, "feature_spec")
            if diffs:
                raise CheckpointError(
                    f"{source}: made for another feature spec ({len(diffs)} "
                    f"difference{'s' if len(diffs) != 1 else ''}: "
                    f"{join_differences(diffs, _MAX_DIFFERENCES)})"
                )

    def __repr__(self) -> str:
        sha = self.metadata.get("model_sha256")
        return (
            f"Compensator({self.input_dim} -> {list(self.config.hidden)} -> {self.output_dim}, "
            f"{self.config.activation}, model_sha256={str(sha)[:12] + '…' if sha else None})"
        )


def _feature_spec_dict(
    spec: FeatureSpec | Mapping[str, Any] | None,
) -> Mapping[str, Any] | None:
    """A feature spec in use as the plain dict it is compared in (None stays None).

    Raises:
        InputError: ``spec`` is neither a FeatureSpec nor a mapping.
    """
    if spec is None or isinstance(spec, Mapping):
        return spec
    if isinstance(spec, FeatureSpec):
        return spec.as_dict()
    raise InputError(
        "expected_feature_spec must be a FeatureSpec or a dict of its fields "
        f"(FeatureSpec.as_dict()), got {type(spec).__name__} {spec!r}"
    )


def _comparable(value: Any) -> Any:
    """Tuples as lists, tensors as lists, recursively: the form feature specs are compared in."""
    if isinstance(value, Mapping):
        return {k: _comparable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_comparable(v) for v in value]
    if isinstance(value, torch.Tensor):
        return value.tolist()
    return value


def _differences(recorded: Any, expected: Any, key: str) -> list[str]:
    """Human-readable differences between two plain values, by dotted key path."""
    out = []
    for path, before, after in value_differences(recorded, expected, key):
        if after is MISSING:
            out.append(f"{path} only in the compensator ({before!r})")
        elif before is MISSING:
            out.append(f"{path} only in the spec in use ({after!r})")
        else:
            out.append(f"{path}: compensator {before!r}, in use {after!r}")
    return out


def _hashable(value: Any) -> Any:
    """``json.dumps``'s ``default`` for :meth:`Compensator.behaviour_sha256`.

    A tensor (or array) becomes its dtype, shape and the SHA-256 of its bytes; a numpy
    scalar its Python number.
    """
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().contiguous().numpy()
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        digest = hashlib.sha256(array.tobytes()).hexdigest()
        return f"array:{array.dtype}:{list(array.shape)}:{digest}"
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot fingerprint a {type(value).__name__}")
