"""Compiled-code machinery of ocreach, one job per module.

* :mod:`ocreach.native.codegen` - C source from CasADi Functions (CasADi's code generator), C
  identifiers, the shared work-array prelude of the hand-written driver loops;
* :mod:`ocreach.native.compile` - the C compiler call and the on-disk cache of shared libraries
  (``$OCREACH_CACHE_DIR``), safe when several processes or hosts build the same kernel at once;
* :mod:`ocreach.native.dop853` - the Dormand-Prince 8(5,3) step as a CasADi Function and its C
  driver loops (one sample at a time, and several samples in SIMD lanes);
* :mod:`ocreach.native.integrator` - :func:`integrate_batch`, the adaptive batch integrator
  (native driver over one or two threads, NumPy fallback);
* :mod:`ocreach.native.batch_eval` - row-wise evaluation of a CasADi Function over a batch in C;
* :mod:`ocreach.native.mc_kernel` - the fused stochastic Monte Carlo kernel (Jain et al. Eq. 1);
* :mod:`ocreach.native.cut_kernel` - the fused CUT moment recursion (Jain et al. Eq. 6, 9-15);
* :mod:`ocreach.intervals.kernel` - a C interpreter of the interval evaluator's schedule
  (:mod:`ocreach.intervals`, ``native=True``) for the few boxes of a ``taylor``/``sdc`` step.

A new kernel gets its own module here, builds its sources with :func:`generate_c` and loads
them with :func:`compile_source`; without a C compiler (or with ``OCREACH_JIT=0``) every caller
falls back to CasADi's VM or NumPy with the same numbers.
"""
from ocreach.native.codegen import C_WORK, c_identifier, generate_c
from ocreach.native.compile import (
                                    COMPILE_ERRORS,
                                    cache_dir,
                                    compile_function,
                                    compile_source,
                                    jit_enabled,
                                    opt_flags,
)

__all__ = ["COMPILE_ERRORS", "C_WORK", "c_identifier", "cache_dir", "compile_function",
           "compile_source", "generate_c", "jit_enabled", "opt_flags"]
