"""Catalog-scale sweeps: many (problem, overrides, method, options) tasks on a distributed engine.

A sweep spec (:mod:`ocreach.sweep.spec`, JSON or TOML) expands into tasks that are plain data;
:func:`run_sweep` sends them through any :class:`concurrent.futures.Executor` (serial, a local
process pool by default, or Dask; :mod:`ocreach.sweep.executors`), each worker builds and caches its
own problems and compiled kernels (:mod:`ocreach.sweep.worker`), and the driver alone writes the
resumable output folder (:mod:`ocreach.sweep.store`).  ``ocreach sweep status|collect DIR``
(:mod:`ocreach.sweep.collect`) summarise and tabulate it.  See ``docs/sweep.md``.
"""
from ocreach.sweep.collect import collect_table, status, write_table
from ocreach.sweep.errors import SweepError
from ocreach.sweep.executors import make_executor
from ocreach.sweep.keys import task_key, versions
from ocreach.sweep.run import RunSummary, run_sweep
from ocreach.sweep.spec import Spec, load_spec, spec_from_dict

__all__ = ["RunSummary", "Spec", "SweepError", "collect_table", "load_spec", "make_executor",
           "run_sweep", "spec_from_dict", "status", "task_key", "versions", "write_table"]
