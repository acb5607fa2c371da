"""Shared by the take tests: a played note's signals and calibration files with changes."""

import dataclasses

import numpy as np
import yaml

from mpipe.measurement.calibration import load_calibration
from mpipe.reed.recorder import RecorderOptions
from mpipe.reed.recording import virtual_recording
from mpipe.reed.take_files import calibration_mapping

FS = 100_000.0


def signals(n=40_000, fs=FS):
    t = np.arange(n) / fs
    env = np.minimum(t / 0.01, 1) * np.minimum((t[-1] - t) / 0.01, 1)
    p = (900 * np.sin(2 * np.pi * 150 * t) + 250 * np.sin(2 * np.pi * 450 * t + 1)) * env
    u = (1e-4 + 8e-5 * np.cos(2 * np.pi * 150 * t - 0.2)) * env
    return p, u


def write_calibration(tmp_path, cal, name="cal.yaml", **mic_changes):
    """Write a calibration file whose microphones take the given per-index changes."""
    mics = list(cal.microphones)
    for key, values in mic_changes.items():
        mics = [dataclasses.replace(m, **{key: v}) for m, v in zip(mics, values, strict=True)]
    path = tmp_path / name
    mapping = calibration_mapping(dataclasses.replace(cal, microphones=tuple(mics)))
    path.write_text(yaml.safe_dump(mapping, sort_keys=False))
    return load_calibration(path)


def virtual_take(cal):
    """A 24-bit virtual take at 48 kHz with mismatched microphones (the ``vtake`` fixtures)."""
    p, u = signals()
    return virtual_recording(
        p,
        u,
        FS,
        cal,
        recorder=RecorderOptions(
            gain_error_db=(0.4, 0.7, -0.5),
            phase_error_deg=(0.0, 1.5, -2.0),
            bits=24,
            fs_out=48_000.0,
        ),
    )
