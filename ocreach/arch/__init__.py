"""The ARCH-COMP NLN suite (``ocreach arch``): the bundled benchmarks of ``problems/arch.py`` run
with a guaranteed method, their specifications checked on the tubes, their measures taken, and
the guaranteed sets checked against sampled truth through the same automaton.

* :mod:`ocreach.arch.suite` -- one instance: warm-up, timed reachability, spec checks, measures;
* :mod:`ocreach.arch.truth` -- sampled truth: escapes from the tubes, counter-examples;
* :mod:`ocreach.arch.report` -- ``arch.csv`` (the ARCH-COMP result format), ``arch.md``,
  ``results.json`` and one figure per benchmark;
* :mod:`ocreach.arch.cli` -- the ``ocreach arch`` command.
"""
