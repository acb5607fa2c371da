"""Running the stages over takes: the pipeline file, ``mpipe run``, manifests, report, results.

Imports every layer below it (:mod:`mpipe.core` to :mod:`mpipe.inversion`), never the
command line.

Modules
-------
settings
    The pipeline file: which calibration, and every stage's settings.
orchestration
    ``mpipe run``: every stage over one or more takes, resumable.
manifest
    What a finished stage used and produced (input hashes), so a run can resume.
report
    The self-contained HTML report of a take.
html_report
    The self-contained HTML page: sections, numbered figures and tables.
results
    A finished run read back (:func:`mpipe.load_run`).
"""


def __getattr__(name: str):
    # mpipe 0.1 had the pipeline file's names in the module mpipe.pipeline. importlib, not
    # "from mpipe.pipeline import ...", which would ask this function again.
    import importlib
    import importlib.util
    import warnings

    if importlib.util.find_spec(f"{__name__}.{name}") is not None:  # a submodule
        return importlib.import_module(f"{__name__}.{name}")
    for where in ("mpipe.pipeline.settings", "mpipe.inversion.settings"):
        module = importlib.import_module(where)
        if hasattr(module, name):
            warnings.warn(
                f"mpipe.pipeline.{name} moved to {where}.{name}", DeprecationWarning, stacklevel=2
            )
            return getattr(module, name)
    raise AttributeError(f"module 'mpipe.pipeline' has no attribute {name!r}")
