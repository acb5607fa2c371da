"""The shipped example: a deterministic virtual take of the simplified clarinet.

:func:`example_take` writes the take that the demo analyses: about 2 s of the Table 1 reed
(Chatziioannou & van Walstijn 2012) played on the simplified clarinet of
``calibration/simplified_clarinet.yaml``, with a slow 10 % mouth-pressure swell, light
breath noise, mean flow from the model, a mild microphone mismatch (with its exact
relative calibration tables) and 45 dB SNR, recorded at 100 kHz in 24-bit FLAC.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
from pathlib import Path

import yaml

from mpipe import __version__
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.core.config import ConfigError, load_yaml
from mpipe.reed.take_files import TakeFiles, take_file_paths

log = logging.getLogger(__name__)

#: The repository's calibration folder (the package is installed in editable mode).
CALIBRATION_DIR = Path(__file__).resolve().parents[2] / "calibration"
#: Instrument and reed of the example.
EXAMPLE_CALIBRATION = CALIBRATION_DIR / "simplified_clarinet.yaml"
EXAMPLE_REED = CALIBRATION_DIR / "reed_table1.yaml"
#: File name of the example take inside the output folder.
EXAMPLE_NAME = "example_take.flac"

#: How the example is made. Microphone 1 is the reference (its errors would only rescale
#: the take); microphones 2 and 3 are off by a few tenths of a dB and of a degree, which
#: the written relative calibration tables correct exactly (physics.md E.6).
EXAMPLE_OPTIONS = SynthOptions(
    duration_s=2.0,
    fs_model=100_000.0,
    fs_out=None,
    temperature_c=None,
    mach="auto",
    snr_db=45.0,
    gain_error_db=(0.0, 0.4, -0.3),
    phase_error_deg=(0.0, 0.5, -0.4),
    swell=0.10,
    breath_noise_pa=20.0,
    onset_s=0.01,
    seed=2012,
    bits=24,
    mic_calibration=True,
)


def example_take(out_dir: str | Path, force: bool = False) -> TakeFiles:
    """Write (or reuse) the example take in ``out_dir``.

    Parameters
    ----------
    out_dir : str or Path
        Output folder; created if needed.
    force : bool
        Regenerate even when an identical example is already there.

    Returns
    -------
    TakeFiles
        Paths of the audio file, sidecar, truth, calibration copy and microphone tables.
        Read the take with ``read_take(files.audio, load_calibration(files.calibration))``.

    Raises
    ------
    OutputExistsError
        When other files of the same names exist and ``force`` is not set.
    """
    out = Path(out_dir) / EXAMPLE_NAME
    planned = take_file_paths(out, EXAMPLE_OPTIONS.mic_calibration)
    if not force and _is_current(planned):
        log.info("reusing the example take %s", out)
        return planned
    return make_take(
        EXAMPLE_CALIBRATION,
        EXAMPLE_REED,
        out,
        EXAMPLE_OPTIONS,
        force=force,
        command="mpipe.cli.examples.example_take()",
    )


def _is_current(files: TakeFiles) -> bool:
    """True when every file exists and the sidecar records this version, recipe and inputs."""
    paths = [files.audio, files.sidecar, files.truth, files.calibration, *files.mic_calibrations]
    if not all(p.exists() for p in paths):
        return False
    try:
        sidecar = load_yaml(files.sidecar)
        recipe = sidecar["recipe"]
    except (ConfigError, KeyError, TypeError):
        return False
    want = yaml.safe_load(yaml.safe_dump(_plain(dataclasses.asdict(EXAMPLE_OPTIONS))))
    return (
        sidecar.get("mpipe_version") == __version__
        and recipe.get("options") == want
        and recipe.get("calibration_sha256") == _sha256(EXAMPLE_CALIBRATION)
        and recipe.get("reed_sha256") == _sha256(EXAMPLE_REED)
    )


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _plain(obj):
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    return obj
