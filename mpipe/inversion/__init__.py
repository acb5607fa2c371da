"""Inverse modelling of the reed: step 1, step 2 and tracking over a take.

Submodules
----------
step1
    Closed-form quasi-static flow fit (paper section 3.1).
rosenbrock
    Rosenbrock's rotating-coordinate search and scipy comparisons (paper section 3.2).
objective
    The step-2 objective F2 and the two ways of starting the model.
tracking
    Per-window inversion over a take, in parallel.
uncertainty
    Standard errors (coloured residual), undetermined directions, identifiable
    combinations (p_M, gamma, zeta, f_r, Q_r) and their coverage.

References
----------
Chatziioannou & van Walstijn 2012, section 3.
"""
