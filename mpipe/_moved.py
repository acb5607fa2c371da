"""Old module paths of mpipe 0.1 (before the subpackages), kept importable with a warning.

``import mpipe.separation`` still works and gives :mod:`mpipe.measurement.separation`, with a
``DeprecationWarning`` naming the new path. A module whose names went to several new
modules (``mpipe.model``: the driver, the compiled kernels, the bore kernel, ...) is given
as a stand-in module that finds each name in the first of them that has it. The names of
the public API (``mpipe.separate``, ``mpipe.track``, ...) did not move; see
``mpipe/__init__.py``.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
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

#: Old module -> further modules that received some of its names.
ALSO = {
    "mpipe.model": (
        "mpipe.reed.bore_kernel",
        "mpipe.reed.kernels",
        "mpipe.reed.playing",
        "mpipe.reed.scheme",
        "mpipe.reed.block_fft",
    ),
    "mpipe.recording": ("mpipe.reed.recorder", "mpipe.reed.take_files", "mpipe.measurement.field"),
    "mpipe.results": ("mpipe.core.units",),
}


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old module name and loads it as the module it moved to."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in MOVED and not fullname.startswith("mpipe.commands."):
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = MOVED.get(spec.name) or spec.name.replace("mpipe.commands.", "mpipe.cli.commands.")
        where = " and ".join((new, *ALSO.get(spec.name, ())))
        warnings.warn(
            f"{spec.name} moved to {where}; import from there", DeprecationWarning, stacklevel=2
        )
        if spec.name not in ALSO:
            return importlib.import_module(new)
        return _StandIn(spec.name, (new, *ALSO[spec.name]))

    def exec_module(self, module):
        pass  # the module it moved to is already executed


class _StandIn(types.ModuleType):
    """An old module whose names now live in several modules."""

    def __init__(self, name: str, targets: tuple[str, ...]):
        super().__init__(name, f"moved to {', '.join(targets)}")
        self._targets = targets

    def __getattr__(self, attr: str):
        if attr.startswith("__"):
            raise AttributeError(attr)
        for target in self._targets:
            module = importlib.import_module(target)
            if hasattr(module, attr):
                return getattr(module, attr)
        raise AttributeError(f"module {self.__name__!r} has no attribute {attr!r}")


def install() -> None:
    """Make the old module paths importable (idempotent)."""
    if not any(isinstance(f, _Alias) for f in sys.meta_path):
        sys.meta_path.insert(0, _Alias())
