"""C source from CasADi Functions, for the kernels of :mod:`ocreach.native`."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import casadi as ca

__all__ = ["C_WORK", "c_identifier", "generate_c"]


def c_identifier(name: str) -> str:
    """``name`` with every non-alphanumeric character replaced by ``_`` (``"anon"`` if empty), for
    the names of generated C functions."""
    return "".join(c if c.isalnum() else "_" for c in name) or "anon"


def generate_c(funs: list[ca.Function]) -> bytes:
    """C source (no header) of the CasADi Functions ``funs``, from CasADi's code generator."""
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator("gen.c", {"with_header": False})
        for fun in funs:
            cg.add(fun)
        cg.generate(tmp + os.sep)
        return Path(tmp, "gen.c").read_bytes()


#: C prelude shared by the generated kernels (batch evaluation, Monte Carlo, CUT):
#: ``OCR_WORK_ALLOC(n_arg, n_res)`` declares CasADi's work arrays ``arg``, ``res``, ``iw``, ``wk``
#: of the Function ``OCR_FUN`` with ``n_arg`` / ``n_res`` spare slots; ``OCR_WORK_FREE`` frees them.
C_WORK = r"""
#include <stdlib.h>
#define OCR_WORK_ALLOC(n_arg, n_res) \
  casadi_int sa, sr, si, sw; \
  OCR_FUN_work(&sa, &sr, &si, &sw); \
  const casadi_real** arg = (const casadi_real**)malloc(sizeof(casadi_real*) * (sa + (n_arg))); \
  casadi_real** res = (casadi_real**)malloc(sizeof(casadi_real*) * (sr + (n_res))); \
  casadi_int* iw = (casadi_int*)malloc(sizeof(casadi_int) * (si + 1)); \
  casadi_real* wk = (casadi_real*)malloc(sizeof(casadi_real) * (sw + 1));
#define OCR_WORK_FREE free(arg); free(res); free(iw); free(wk);
"""
