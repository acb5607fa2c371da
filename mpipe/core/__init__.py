"""Foundations every layer may use; imports nothing else of mpipe.

Modules
-------
errors
    Errors the user can fix, reported as one line.
config
    YAML into validated frozen dataclasses whose fields carry unit and meaning.
units
    The unit of every named quantity in mpipe's tables and signals.
io
    Atomic writes, no overwriting without ``force``, output-folder locks.
filters
    Filters shared by the measurement chain and the model comparison.
workers
    Worker processes that end with their parent.
cluster
    A Dask scheduler's address checked, and whether it answers as a scheduler.
progress
    Progress bars (tqdm) for long stages.
harmonic_fit
    Least squares of a constant and harmonics on many frames at once.
"""
