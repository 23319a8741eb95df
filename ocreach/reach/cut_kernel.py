"""Transition re-export: the fused CUT kernel lives in :mod:`ocreach.native.cut_kernel`."""
from ocreach.native.cut_kernel import CUTKernel, cut_kernel, point_function  # noqa: F401

__all__ = ["CUTKernel", "cut_kernel", "point_function"]
