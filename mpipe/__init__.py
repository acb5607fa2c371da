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
    "load_calibration": "mpipe.measurement.calibration",
    "load_pipeline": "mpipe.pipeline.settings",
    "load_reed": "mpipe.reed.parameters",
    "ReedParameters": "mpipe.reed.parameters",
    "input_impedance": "mpipe.acoustics.bore",
    "reflection_function": "mpipe.acoustics.reflection",
    "prepare_bore": "mpipe.reed.bore_kernel",
    "simulate": "mpipe.reed.model",
    "make_controls": "mpipe.reed.controls",
    "play": "mpipe.reed.controls",
    "load_score": "mpipe.reed.score",
    "score_controls": "mpipe.reed.score",
    "virtual_recording": "mpipe.reed.recording",
    "read_take": "mpipe.measurement.takes",
    "separate": "mpipe.measurement.separation.stage",
    "SeparationConfig": "mpipe.measurement.separation.settings",
    "translate": "mpipe.measurement.translation",
    "TranslationConfig": "mpipe.measurement.translation",
    "validate": "mpipe.measurement.validation",
    "ValidationConfig": "mpipe.measurement.validation",
    "steady_windows": "mpipe.inversion.preparation.conditioning",
    "plan_inversion": "mpipe.inversion.preparation.conditioning",
    "plan_take": "mpipe.inversion.preparation.conditioning",
    "bore_resonances": "mpipe.inversion.preparation.conditioning",
    "segment_take": "mpipe.inversion.preparation.segments",
    "segment_summary": "mpipe.inversion.trust.notes",
    "yin_f0": "mpipe.measurement.pitch",
    "bore_kernel": "mpipe.inversion.preparation.kernel",
    "take_temperature": "mpipe.inversion.preparation.kernel",
    "step1": "mpipe.inversion.fit.step1",
    "track": "mpipe.inversion.whole_take.tracking",
    "WindowPlan": "mpipe.inversion.whole_take.tracking",
    "RunOptions": "mpipe.inversion.whole_take.tracking",
    "invert_take": "mpipe.inversion.whole_take.take",
    "resynthesise": "mpipe.inversion.output.resynthesis",
    "run_take": "mpipe.pipeline.orchestration",
    "load_run": "mpipe.pipeline.results",
    "RunData": "mpipe.pipeline.results",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        return getattr(import_module(_API[name]), name)
    raise AttributeError(f"module 'mpipe' has no attribute {name!r}")
