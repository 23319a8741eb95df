"""Numbers from a model: trajectories and their sensitivities, discretisations, sampling rules.

* :mod:`~ocreach.dynamics.flow` -- trajectories, batches of them (the compiled adaptive
  integrator of :mod:`ocreach.native`), STMs and STTs along a reference;
* :mod:`~ocreach.dynamics.discretize` -- the discrete RK4 prediction model ``x+ = g(x, u)``;
* :mod:`~ocreach.dynamics.shooting` -- multiple shooting with minimum-norm Newton updates;
* :mod:`~ocreach.dynamics.stochastic_mc` -- the stochastic Monte Carlo (Jain et al. Eq. 1);
* :mod:`~ocreach.dynamics.quadrature` -- CUT, UT and tensor rules for expectations.

May import: models, the model, sets, :mod:`ocreach.native` and the helpers; never problems or
methods.
"""
