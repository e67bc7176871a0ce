"""Measure the speed/accuracy trade-offs of the integrators (``taichi-sim bench ...``, ``advise``).

Modules:

* :mod:`.theory`: the fastest mode omega_max of a scene (a cheap Gershgorin bound, power
  iteration on the linearised stiffness matrix) and the predicted stability limits C / omega_max
  (docs/integrators.md, Stability on an oscillator). ``simulate`` uses it to warn about a step
  beyond the limit.
* :mod:`.workprec`: work-precision sweeps (error against cost) and observed orders.
* :mod:`.stability`: the largest stable step per integrator, found by bisection, against theory.
* :mod:`.throughput`: particle-steps per second against grid size, precision and scene
  features, with the Taichi and warp peers timed in their own subprocesses.
* :mod:`.advise`: the stability table; :mod:`.advise_target`: the (integrator, step) that
  reaches a target error in the least wall time, measured against a reference run.

Importing this package does not call ``ti.init``; matplotlib (plots) and scipy (reference
solutions, a cross-check of omega_max) are optional (``pip install 'taichi_sim[bench]'``).
"""
