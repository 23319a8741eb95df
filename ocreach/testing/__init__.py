"""Testing helpers: the soundness harness that holds every guaranteed method to one test.

* :mod:`ocreach.testing.strategies` -- generated polynomial / rational systems (hypothesis
  strategies and seeded draws from one generator);
* :mod:`ocreach.testing.truth` -- the independent truth (SciPy DOP853 at tight tolerance) and
  its samples (vertices, interior, bang-bang and random inputs);
* :mod:`ocreach.testing.containment` -- is a truth point inside a guaranteed set (exact gauge on
  zonotopes and unions, certificates on polynomial zonotopes);
* :mod:`ocreach.testing.harness` -- the registry's guaranteed methods on cases, outcomes, summary;
* :mod:`ocreach.testing.mutants` -- deliberately broken copies (a scaled remainder) that the
  harness must catch.

A layer above :mod:`ocreach.reach` (it runs methods on problems); nothing in the package imports
it.  ``hypothesis`` is needed only for :func:`ocreach.testing.strategies.systems`.
"""
from ocreach.testing.harness import (
    Case,
    Outcome,
    bundled_cases,
    generated_case,
    guaranteed_methods,
    run_all,
    run_method,
    summary,
)
from ocreach.testing.strategies import (
    DISTURBED,
    GENERAL,
    QUADRATIC,
    REMAINDER_DOMINATED,
    GeneratedSystem,
    Ranges,
    generate,
    seeded_system,
    systems,
)

__all__ = ["DISTURBED", "GENERAL", "QUADRATIC", "REMAINDER_DOMINATED", "Case", "GeneratedSystem", "Outcome", "Ranges",
           "bundled_cases", "generate", "generated_case", "guaranteed_methods", "run_all",
           "run_method", "seeded_system", "summary", "systems"]
