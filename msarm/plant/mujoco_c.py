"""MuJoCo's own C functions, callable from compiled (numba) code.

The plant's hot loop is four plant steps per control period, each ``mj_step1``, the cable
kernel and ``mj_step2``. Called from Python, every MuJoCo call and every launch of the cable
kernel crosses the interpreter (about 20 us a control period on the development machine, as
much as MuJoCo's own work). This module looks up ``mj_step1`` and ``mj_step2`` in the very
``libmujoco`` that the ``mujoco`` package loaded and gives a numba intrinsic that calls such
a ``void f(const mjModel*, mjData*)`` through its address, so that the whole loop runs
compiled (:func:`msarm.plant.cable_kernel.step_plant`). The functions called are MuJoCo's
own, on the same ``mjModel``/``mjData`` the Python bindings wrap (``_address``): the results
are the same bits as the Python loop's (tested).

Where the library or the addresses cannot be found (another MuJoCo build, another platform),
:func:`step_functions` returns None and the plant keeps its Python loop.
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import mujoco
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["StepFunctions", "call_model_data", "step_functions"]


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
def step_functions() -> StepFunctions | None:
    """The addresses of ``mj_step1``/``mj_step2`` in the loaded libmujoco, or None if not found."""
    folder = Path(mujoco.__file__).parent
    for candidate in sorted(folder.glob("libmujoco.so*")) + sorted(folder.glob("libmujoco*.dylib")):
        try:
            library = ctypes.CDLL(str(candidate))
            step1 = ctypes.cast(library.mj_step1, ctypes.c_void_p).value
            step2 = ctypes.cast(library.mj_step2, ctypes.c_void_p).value
        except (OSError, AttributeError):
            continue
        if step1 and step2:
            return StepFunctions(step1, step2)
    return None


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
