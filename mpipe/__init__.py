"""mpipe: clarinet reed parameters from in-bore recordings, by inverse modelling.

Chatziioannou & van Walstijn (2012), "Estimation of clarinet reed parameters by inverse
modelling", Acta Acustica united with Acustica 98(4):629-639.

Every stage is callable on arrays and configuration objects; the names below are imported
on first use (so ``import mpipe`` stays light)::

    cal = mpipe.load_calibration("calibration/simplified_clarinet.yaml")
    take = mpipe.read_take("take.flac", cal)
    sep = mpipe.separate(take.pressures, take.fs, cal, mpipe.SeparationConfig())
"""

from importlib import import_module

__version__ = "0.1.0"

_API = {
    "load_calibration": "mpipe.calibration",
    "load_pipeline": "mpipe.pipeline",
    "load_reed": "mpipe.reed",
    "ReedParameters": "mpipe.reed",
    "input_impedance": "mpipe.bore",
    "reflection_function": "mpipe.reflection",
    "prepare_bore": "mpipe.model",
    "simulate": "mpipe.model",
    "virtual_recording": "mpipe.recording",
    "read_take": "mpipe.takes",
    "separate": "mpipe.separation",
    "SeparationConfig": "mpipe.separation",
    "translate": "mpipe.translation",
    "TranslationConfig": "mpipe.translation",
    "validate": "mpipe.validation",
    "ValidationConfig": "mpipe.validation",
    "steady_windows": "mpipe.conditioning",
    "plan_inversion": "mpipe.conditioning",
    "bore_kernel": "mpipe.inversion.kernel",
    "take_temperature": "mpipe.inversion.kernel",
    "step1": "mpipe.inversion.step1",
    "track": "mpipe.inversion.tracking",
    "resynthesise": "mpipe.resynthesis",
    "run_take": "mpipe.orchestration",
    "load_run": "mpipe.results",
    "RunData": "mpipe.results",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        return getattr(import_module(_API[name]), name)
    raise AttributeError(f"module 'mpipe' has no attribute {name!r}")
