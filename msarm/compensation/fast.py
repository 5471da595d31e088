"""A numpy fast path of :class:`msarm.compensation.checkpoint.Compensator` for control loops.

:class:`FastCompensator` evaluates the trained network for one sample per call (a 250 Hz
feedforward) without torch: its weights are exported once to contiguous float64 numpy arrays
and every call writes into preallocated buffers.

The normalisation is folded into the first and last layers at construction: with
``x̂ = (x - μx) / σx`` and ``y = σy ŷ + μy``,

- first layer: ``W1 x̂ + b1 = (W1 / σx) x + (b1 - (W1 / σx) μx)``;
- last layer: ``σy (W_L h + b_L) + μy = (σy W_L) h + (σy b_L + μy)``;

so a call is, per layer, one matrix-vector product, one bias addition and (hidden layers) one
activation, all in place. The result equals :meth:`Compensator.predict` to round-off (a test
keeps them within 1e-6).

A NaN or inf in ``x`` raises :class:`msarm.errors.InputError`, checked at the cost of one
scalar test: any non-finite input makes every pre-activation of the first layer non-finite
(``inf · 0`` is NaN), so only the first one is tested, and the full input is scanned only to
name the bad column.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.compensation.checkpoint import Compensator
from msarm.compensation.network import as_feature_array, check_finite
from msarm.errors import InputError

__all__ = ["FastCompensator"]

FloatArray = NDArray[np.float64]


def _tanh(values: FloatArray) -> None:
    np.tanh(values, out=values)


def _relu(values: FloatArray) -> None:
    np.maximum(values, 0.0, out=values)


_ACTIVATIONS = {"tanh": _tanh, "relu": _relu}


class FastCompensator:
    """Single-sample numpy evaluation of a trained :class:`Compensator`.

    Not thread-safe: every call reuses the same buffers (make one per thread).

    Attributes:
        input_dim: Number of inputs ``d``.
        output_dim: Number of outputs ``n``.
    """

    def __init__(self, compensator: Compensator) -> None:
        """Export the compensator's weights, with the normalisation folded in.

        Args:
            compensator: The trained compensator (its weights are copied; later changes to it
                do not reach this object).
        """
        if not isinstance(compensator, Compensator):
            raise InputError(
                f"FastCompensator needs a Compensator, got {type(compensator).__name__}"
            )
        layers = compensator.layer_weights()
        x_mean = compensator.input_normalizer.mean
        x_std = compensator.input_normalizer.std
        y_mean = compensator.output_normalizer.mean
        y_std = compensator.output_normalizer.std
        w_first, b_first = layers[0]
        w_first = w_first / x_std[np.newaxis, :]
        layers[0] = (w_first, b_first - w_first @ x_mean)
        w_last, b_last = layers[-1]
        layers[-1] = (y_std[:, np.newaxis] * w_last, y_std * b_last + y_mean)
        self._weights = tuple(np.ascontiguousarray(w, dtype=np.float64) for w, _ in layers)
        self._biases = tuple(np.ascontiguousarray(b, dtype=np.float64) for _, b in layers)
        self._buffers = tuple(np.empty(b.shape[0], dtype=np.float64) for b in self._biases)
        self._activation = _ACTIVATIONS[compensator.config.activation]
        self._hidden = tuple(
            zip(self._weights[:-1], self._biases[:-1], self._buffers[:-1], strict=True)
        )
        self.input_dim = compensator.input_dim
        self.output_dim = compensator.output_dim

    def __call__(self, x: ArrayLike, out: FloatArray | None = None) -> FloatArray:
        """Predict the joint-torque errors of one sample (or, more slowly, of a batch).

        Args:
            x: Features, shape ``(d,)`` (float64 for the fast path); ``(N, d)`` is accepted
                and evaluated without the preallocated buffers.
            out: Optional float64 array of shape ``(n,)`` to write the result into (single
                samples only); saves the allocation of a new array.

        Returns:
            Predicted targets [N·m], shape ``(n,)`` (``out`` if given) or ``(N, n)``.

        Raises:
            InputError: Wrong shape (a ragged sequence too), or a NaN or inf in ``x`` (column
                named).
        """
        if (
            type(x) is not np.ndarray
            or x.ndim != 1
            or x.shape[0] != self.input_dim
            or x.dtype != np.float64
        ):
            return self._general(x, out)
        h = x
        for weight, bias, buffer in self._hidden:
            np.dot(weight, h, out=buffer)
            buffer += bias
            if h is x and not math.isfinite(buffer[0]):
                self._raise_bad_input(x)
            self._activation(buffer)
            h = buffer
        result = self._buffers[-1]
        np.dot(self._weights[-1], h, out=result)
        result += self._biases[-1]
        if h is x and not math.isfinite(result[0]):  # no hidden layer
            self._raise_bad_input(x)
        if out is None:
            return result.copy()
        if type(out) is not np.ndarray or out.shape != result.shape or out.dtype != np.float64:
            raise InputError(
                f"FastCompensator: out must be a float64 array of shape ({self.output_dim},)"
            )
        out[...] = result
        return out

    def predict_batch(self, x: ArrayLike) -> FloatArray:
        """Predict a batch: features ``(N, d)`` to targets ``(N, n)`` [N·m].

        Args:
            x: Features, shape ``(N, d)``, finite.

        Returns:
            Predicted targets [N·m], shape ``(N, n)``, a new array.

        Raises:
            InputError: ``x`` is not of shape ``(N, d)`` (a ragged sequence too), or holds a
                NaN or inf (row and column named).
        """
        array = as_feature_array(x, f"(N, {self.input_dim})")
        if array.ndim != 2 or array.shape[1] != self.input_dim:
            raise InputError(
                f"FastCompensator.predict_batch expects shape (N, {self.input_dim}), "
                f"got {array.shape}"
            )
        check_finite("x", array)
        h = array
        for weight, bias in zip(self._weights[:-1], self._biases[:-1], strict=True):
            h = h @ weight.T
            h += bias
            self._activation(h)
        y = h @ self._weights[-1].T
        y += self._biases[-1]
        return y

    def _general(self, x: ArrayLike, out: FloatArray | None) -> FloatArray:
        """Slow path: convert, check the shape, and evaluate one sample or a batch."""
        array = as_feature_array(x, f"({self.input_dim},) or (N, {self.input_dim})")
        if array.ndim == 2:
            if out is not None:
                raise InputError("FastCompensator: out is only supported for one sample (d,)")
            return self.predict_batch(array)
        if array.ndim != 1 or array.shape[0] != self.input_dim:
            raise InputError(
                f"FastCompensator expects shape ({self.input_dim},) or (N, {self.input_dim}), "
                f"got {array.shape}"
            )
        return self(np.ascontiguousarray(array), out)

    def _raise_bad_input(self, x: FloatArray) -> None:
        check_finite("x", x[np.newaxis, :])
        raise InputError(
            "FastCompensator: the first layer overflowed (|x| too large for float64); "
            f"max |x| = {float(np.max(np.abs(x)))!r}"
        )
