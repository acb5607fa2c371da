"""Inverse modelling of the reed: step 1, step 2, tracking, uncertainty and resynthesis.

Imports :mod:`mpipe.core`, :mod:`mpipe.acoustics`, :mod:`mpipe.measurement` and
:mod:`mpipe.reed`.

Submodules
----------
settings
    The pipeline sections ``conditioning``, ``inversion``, ``resynthesis``, ``executor``.
conditioning
    Steady windows, filtering, period and synchronisation shared by F2 and the resynthesis.
kernel
    The bore kernel of a take, at one documented temperature.
step1
    Closed-form quasi-static flow fit (paper section 3.1).
rosenbrock
    Rosenbrock's rotating-coordinate search and scipy comparisons (paper section 3.2).
objective
    The step-2 objective F2 and the two ways of starting the model.
tracking
    Per-window inversion over a take, in parallel.
least_squares, coldstart
    Trust-region search on F2's residual vector; the global cold start.
fastpath
    The compiled evaluation of F2 (the inner loop).
status
    ok, or why a window's numbers should not be trusted.
uncertainty
    Standard errors (coloured residual), undetermined directions, identifiable
    combinations (p_M, gamma, zeta, f_r, Q_r) and their coverage.
resynthesis
    The model driven by each window's estimates, and its figures.

References
----------
Chatziioannou & van Walstijn 2012, section 3.
"""
