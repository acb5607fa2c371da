"""Running the stages over takes: the pipeline file, ``mpipe run``, manifests, report, results.

Imports every layer below it (:mod:`mpipe.core` to :mod:`mpipe.inversion`), never the
command line.

Modules
-------
settings
    The pipeline file: which calibration, and every stage's settings.
orchestration
    ``mpipe run``: every stage over one or more takes, resumable.
batch
    Several takes side by side, each take's stages on a worker of its own.
session
    A recording session's file: its takes, each with its calibration and fingering.
session_table
    A session's tables: one row per note per take, one row per take.
manifest
    What a finished stage used and produced (input hashes), so a run can resume.
report
    The self-contained HTML report of a take.
html_report
    The self-contained HTML page: sections, numbered figures and tables.
results
    A finished run read back (:func:`mpipe.load_run`).
"""
