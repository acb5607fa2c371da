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
    Closed-form quasi-static flow fit (paper section 3.1): both branches and p_m.
flow_fit
    Step 1's fit of one branch: regressors, exact least squares, sample refinement.
mouth_pressure
    Step 1's p_m: the minimiser of the profiled flow misfit.
rosenbrock
    Rosenbrock's rotating-coordinate search (paper section 3.2), the reference step-2 search.
objective
    The step-2 objective F2 and the two ways of starting the model.
history_start
    The model started from the target's past: the reed's lead-in, the missing mean flow.
tracking
    Per-window inversion over a take: one shared cold start, warm windows, cold retries.
window
    One window's inversion: step 1, the cold or warm start, step 2, its errors.
execution
    Where windows run: in process, a local process pool or a Dask cluster.
records
    The window record (a window's result and its correlation) and the table's schema:
    every column's dtype, unit and meaning; typed CSV and Parquet files.
tables
    A window's blank record, checkpoints, the files written.
least_squares, coldstart
    Trust-region search on F2's residual vector; the global cold start.
fastpath
    The compiled evaluation of F2 (the inner loop).
sensitivities
    F2's Jacobian from the model's forward sensitivities (one run for every parameter).
status
    ok, or why a window's numbers should not be trusted.
uncertainty
    Covariance of the estimates (coloured residual) and undetermined directions.
combinations
    Identifiable combinations (p_M, gamma, zeta, f_r, Q_r) and their standard errors.
window_errors
    The uncertainty columns of a window's row (standard errors, determined, notes).
coverage
    Summary of a take's uncertainty: MAD sigma, median SE, determined, 2-SE coverage.
resynthesis
    The model driven by each window's estimates, and its figures.

References
----------
Chatziioannou & van Walstijn 2012, section 3.
"""
