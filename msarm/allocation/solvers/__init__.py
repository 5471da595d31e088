"""Allocation solvers, one module each; pick one by name with ``make_allocator``."""

from msarm.allocation.solvers.base import Allocator
from msarm.allocation.solvers.closed_form import ClosedFormAllocator, ImprovedClosedFormAllocator
from msarm.allocation.solvers.cvxpy_solver import CvxpyAllocator
from msarm.allocation.solvers.daqp_solver import DaqpAllocator

__all__ = [
    "Allocator",
    "ClosedFormAllocator",
    "CvxpyAllocator",
    "DaqpAllocator",
    "ImprovedClosedFormAllocator",
]
