"""Inverse modelling of the reed: step 1, step 2, tracking, uncertainty and resynthesis.

Imports :mod:`mpipe.core`, :mod:`mpipe.acoustics`, :mod:`mpipe.measurement` and
:mod:`mpipe.reed`.

Rooms
-----
The inversion's modules live in rooms by concern, listed from the bottom up: a room imports the
floor (the settings) and the rooms before it, never one after it (tests/inversion/test_rooms.py
checks every import, function-level ones included). Each room's docstring lists its modules.

settings, conditioning_settings
    The settings of every stage (the floor: every room imports them, they import no room).
preparation/
    What the fit is given: the span, the notes, the conditioning, the bore kernel. Modules:
    span, segments, conditioning, kernel, boundaries.
trust/
    What a result is worth: uncertainty, its budget, statuses, take-level checks. Modules:
    harmonics, uncertainty, combinations, budget, window_errors, discretisation, notes, status,
    status_words, diagnostics.
table/
    The windows table: the record, its schema, the files written, the coverage. Modules:
    records, tables, coverage.
fit/
    One window's fit: step 1, F2, its Jacobian, the searches, where windows run. Modules:
    flow_fit, mouth_pressure, step1, history_start, objective, fastpath, sensitivities,
    rosenbrock, least_squares, coldstart, window, execution.
pooling/
    The normal equations of a joint fit: windows, notes and the take, their elimination and
    covariance. Modules: take_system.
whole_take/
    A whole take: its one fit, the per-window tracking, take-wide errors, invert_take.
    Modules: tracking, temperature, shared_errors, frontend_propagation, estimator, take_fit,
    take_shards, take_rows, take_estimate, take.
output/
    What a take's result shows: the resynthesis and the figures. Modules: resynthesis,
    tracks_plot, note_figures, resynthesis_stream.

References
----------
Chatziioannou & van Walstijn 2012, section 3.
"""
