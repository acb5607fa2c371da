"""Old module paths of mpipe 0.1 (before the subpackages), kept importable with a warning.

``import mpipe.separation`` still works and gives :mod:`mpipe.measurement.separation`, with a
``DeprecationWarning`` naming the new path. The names of the public API (``mpipe.separate``,
``mpipe.track``, ...) did not move; see ``mpipe/__init__.py``.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: Old module -> new module.
MOVED = {
    "mpipe.errors": "mpipe.core.errors",
    "mpipe.io": "mpipe.core.io",
    "mpipe.config": "mpipe.core.config",
    "mpipe.workers": "mpipe.core.workers",
    "mpipe.progress": "mpipe.core.progress",
    "mpipe.filters": "mpipe.core.filters",
    "mpipe.air": "mpipe.acoustics.air",
    "mpipe.ducts": "mpipe.acoustics.ducts",
    "mpipe.radiation": "mpipe.acoustics.radiation",
    "mpipe.bore": "mpipe.acoustics.bore",
    "mpipe.reflection": "mpipe.acoustics.reflection",
    "mpipe.calibration": "mpipe.measurement.calibration",
    "mpipe.takes": "mpipe.measurement.takes",
    "mpipe.mic_calibration": "mpipe.measurement.microphones",
    "mpipe.separation": "mpipe.measurement.separation",
    "mpipe.translation": "mpipe.measurement.translation",
    "mpipe.validation": "mpipe.measurement.validation",
    "mpipe.impedance": "mpipe.measurement.impedance",
    "mpipe.measured_impedance": "mpipe.measurement.measured_impedance",
    "mpipe.model": "mpipe.reed.model",
    "mpipe.recording": "mpipe.reed.recording",
    "mpipe.conditioning": "mpipe.inversion.conditioning",
    "mpipe.resynthesis": "mpipe.inversion.resynthesis",
    "mpipe.orchestration": "mpipe.pipeline.orchestration",
    "mpipe.manifest": "mpipe.pipeline.manifest",
    "mpipe.report": "mpipe.pipeline.report",
    "mpipe.results": "mpipe.pipeline.results",
    "mpipe.demo": "mpipe.cli.demo",
    "mpipe.examples": "mpipe.cli.examples",
    "mpipe.commands": "mpipe.cli.commands",
}


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old module name and loads it as the module it moved to."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in MOVED and not fullname.startswith("mpipe.commands."):
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = MOVED.get(spec.name) or spec.name.replace("mpipe.commands.", "mpipe.cli.commands.")
        warnings.warn(
            f"{spec.name} moved to {new}; import it from there", DeprecationWarning, stacklevel=2
        )
        return importlib.import_module(new)

    def exec_module(self, module):
        pass  # the module it moved to is already executed


def install() -> None:
    """Make the old module paths importable (idempotent)."""
    if not any(isinstance(f, _Alias) for f in sys.meta_path):
        sys.meta_path.insert(0, _Alias())
