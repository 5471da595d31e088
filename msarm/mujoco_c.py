"""MuJoCo's own C functions, callable from compiled (numba) code.

Two hot loops call MuJoCo thousands of times with a little arithmetic in between: the arm
plant's step loop (``mj_step1``, the cable kernel, ``mj_step2``, four times a control period)
and the cable kinematics of every logged posture that the diagnosis and the compensator's
target need (``mj_kinematics``, ``mj_comPos``, ``mj_tendon``). Called from Python, every MuJoCo
call crosses the interpreter (about 3 us each on the development machine, as much as
MuJoCo's own work). This module looks those functions up in the very ``libmujoco`` that the
``mujoco`` package loaded and gives a numba intrinsic that calls such a
``void f(const mjModel*, mjData*)`` through its address, so that a whole loop runs compiled
(:func:`msarm.plant.cable_kernel.step_plant`, :mod:`msarm.muscle.batch_kinematics`). The
functions called are MuJoCo's own, on the same ``mjModel``/``mjData`` the Python bindings wrap
(``_address``): the results are the same bits as the Python loops' (tested).

Where the library or a function cannot be found (another MuJoCo build, another platform),
:func:`function_addresses` and :func:`step_functions` return None and the callers keep their
Python loops.
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import mujoco
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["StepFunctions", "call_model_data", "function_addresses", "step_functions"]


class StepFunctions:
    """Addresses of MuJoCo's ``mj_step1`` and ``mj_step2`` (for :func:`call_model_data`).

    Attributes:
        step1: Address of ``mj_step1``.
        step2: Address of ``mj_step2``.
    """

    def __init__(self, step1: int, step2: int) -> None:
        self.step1 = step1
        self.step2 = step2


@functools.cache
def function_addresses(*names: str) -> tuple[int, ...] | None:
    """Addresses of the named functions in the loaded libmujoco, or None if any is not found.

    Args:
        names: MuJoCo function names, e.g. ``"mj_kinematics"``.
    """
    folder = Path(mujoco.__file__).parent
    for candidate in sorted(folder.glob("libmujoco.so*")) + sorted(folder.glob("libmujoco*.dylib")):
        try:
            library = ctypes.CDLL(str(candidate))
            addresses = tuple(
                ctypes.cast(getattr(library, name), ctypes.c_void_p).value for name in names
            )
        except (OSError, AttributeError):
            continue
        if all(addresses):
            return addresses  # type: ignore[return-value]
    return None


def step_functions() -> StepFunctions | None:
    """The addresses of ``mj_step1``/``mj_step2`` in the loaded libmujoco, or None if not found."""
    addresses = function_addresses("mj_step1", "mj_step2")
    return None if addresses is None else StepFunctions(*addresses)


@intrinsic
def call_model_data(typingctx, function, model, data):
    """Call the C function at address ``function`` as ``function(model, data)`` (numba only).

    Args (all integers, as numba ``intp``): the address of a ``void (const mjModel*, mjData*)``
    function, and the addresses of the ``mjModel`` and ``mjData`` (``MjModel._address``).
    """
    signature = types.void(types.intp, types.intp, types.intp)

    def codegen(context, builder, sig, args):
        pointer = ir.IntType(8).as_pointer()
        function_type = ir.FunctionType(ir.VoidType(), [pointer, pointer])
        callee = builder.inttoptr(args[0], function_type.as_pointer())
        model, data = (builder.inttoptr(address, pointer) for address in args[1:])
        builder.call(callee, [model, data])
        return context.get_dummy_value()

    return signature, codegen
