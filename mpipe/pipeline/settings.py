"""The pipeline file: which calibration to use and how to run each stage.

One YAML file per analysis (see ``pipelines/simplified_clarinet.yaml``). It is parsed once
into the frozen dataclasses below; unknown keys are errors naming the file and the key path.

Extending
---------
A stage adds its own section by declaring a configuration dataclass (``spec`` fields) and
adding one field to :class:`PipelineConfig`, with a default so that older pipeline files stay
valid. The loader needs no change: :func:`mpipe.core.config.build` walks the type hints.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from mpipe.core.config import (
    ConfigError,
    Where,
    build,
    load_yaml,
    spec,
    to_commented_yaml,
)
from mpipe.inversion.settings import (
    PARAMETER_NAMES,
    ConditioningConfig,
    ExecutorConfig,
    InversionConfig,
    ModelLowPass,
    ParameterBounds,
    ResynthesisConfig,
)
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.translation import TranslationConfig
from mpipe.measurement.validation import ValidationConfig


@dataclass(frozen=True)
class PipelineConfig:
    """A whole pipeline file."""

    calibration: str = spec(
        "",
        "calibration file, relative to the pipeline file (`mpipe run --calibration` and "
        "`mpipe separate` take theirs instead)",
    )
    fingering: str | None = spec(
        "",
        "the fingering played, a name of the calibration's fingerings (null: the "
        "calibration's default)",
        default=None,
    )
    separation: SeparationConfig = spec(
        "", "wave separation (two or more microphones)", default=SeparationConfig()
    )
    translation: TranslationConfig = spec(
        "", "translation to the mouthpiece and low-pass", default=TranslationConfig()
    )
    validation: ValidationConfig = spec(
        "", "impedance validation against theory", default=ValidationConfig()
    )
    conditioning: ConditioningConfig = spec(
        "", "segments and the windows inverted", default=ConditioningConfig()
    )
    inversion: InversionConfig = spec("", "step 1, step 2 and tracking", default=InversionConfig())
    resynthesis: ResynthesisConfig = spec("", "resynthesis outputs", default=ResynthesisConfig())
    executor: ExecutorConfig = spec("", "parallel execution", default=ExecutorConfig())
    source: str = spec("", "file the pipeline was read from (set by the loader)", default="")

    @property
    def calibration_path(self) -> Path:
        """Absolute path of the calibration file."""
        return (Path(self.source).parent / self.calibration).resolve()


PIPELINE_HEADER = """\
# mpipe pipeline: how to run every stage (Chatziioannou & van Walstijn 2012, sections 3-4).
# SI units throughout (temperatures in degC); each key's unit is in [brackets] before it.
# Every key is optional except `calibration`; a missing key takes the value shown by
# `mpipe config` (which printed this file).
"""


def pipeline_yaml(cfg: PipelineConfig | None = None, calibration: str | None = None) -> str:
    """The pipeline as commented YAML: every key of every stage, with unit and meaning.

    Parameters
    ----------
    cfg : PipelineConfig, optional
        The pipeline to write (default: every default, and ``calibration`` as given).
    calibration : str, optional
        Calibration path to write (default: the one of ``cfg``, or a placeholder).

    Returns
    -------
    str
        YAML that :func:`load_pipeline` reads back into an equal configuration.
    """
    if cfg is None:
        cfg = PipelineConfig(calibration=calibration or "CALIBRATION.yaml")
    elif calibration is not None:
        cfg = replace(cfg, calibration=calibration)
    return PIPELINE_HEADER + to_commented_yaml(cfg, skip=("source",))


def load_pipeline(path: str | Path, check_calibration: bool = True) -> PipelineConfig:
    """Read and validate a pipeline file.

    Parameters
    ----------
    path : str or Path
        YAML file.
    check_calibration : bool
        Refuse a ``calibration`` that names no file; False when the command is given
        another calibration (``mpipe run --calibration``, ``mpipe separate``, ``mpipe
        config``), so that the placeholder ``mpipe config`` writes does not block it.

    Returns
    -------
    PipelineConfig

    Raises
    ------
    ConfigError
        Naming the file, the key path and what was expected; also when the calibration
        file it refers to does not exist.
    """
    data = dict(load_yaml(path))
    if "calibration" not in data and {"bore", "microphones"} & set(data):
        raise ConfigError(
            f"{path}: this is a calibration file (it has bore/microphones); expected a "
            "pipeline file here (`mpipe config -o PIPE.yaml` writes one)"
        )
    if "source" in data:
        raise ConfigError(f"{path}: source: this key is set by the loader, remove it")
    data["source"] = str(Path(path).resolve())
    inversion = data.get("inversion")
    for key in ("lowpass_hz", "lowpass"):
        if isinstance(inversion, dict) and key in inversion:
            raise ConfigError(
                f"{path}: inversion.{key}: the model is low-passed with the measurement's "
                "filter: set translation.lowpass_hz, transition_hz and stopband_db instead"
            )
    cfg = build(PipelineConfig, data, Where(str(path)))
    # one low-pass for both sides: the model's is the translation's
    cfg = replace(cfg, inversion=replace(cfg.inversion, lowpass=ModelLowPass.of(cfg.translation)))
    if check_calibration and not cfg.calibration_path.is_file():
        raise ConfigError(f"{path}: calibration: no such file {cfg.calibration_path}")
    _check_window(cfg, path)
    return cfg


def _check_window(cfg: PipelineConfig, path: str | Path) -> None:
    """A window must hold one period of the lowest playing frequency (its f0 is measured)."""
    shortest = 1.0 / cfg.conditioning.f0_min_hz
    if cfg.inversion.window_s < shortest:
        raise ConfigError(
            f"{path}: inversion.window_s: {cfg.inversion.window_s:g} s holds less than one "
            f"period of the lowest playing frequency conditioning.f0_min_hz = "
            f"{cfg.conditioning.f0_min_hz:g} Hz; expected at least {shortest:.3g} s"
        )


__all__ = [
    "PARAMETER_NAMES",
    "ExecutorConfig",
    "InversionConfig",
    "ParameterBounds",
    "PipelineConfig",
    "load_pipeline",
    "pipeline_yaml",
]
