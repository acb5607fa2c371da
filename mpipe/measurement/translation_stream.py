"""The translation of a take on disk, block by block: the numbers of :func:`translate`.

:func:`translate_to_npz` reads p0, u0 and the temperature from the separation's file
(slices of :class:`mpipe.core.signals.DiskArray`), translates them in the blocks of
:class:`mpipe.measurement.translation.TranslationPlan` into a scratch file, then low-passes
every signal in the blocks of :func:`mpipe.core.filters.apply_lowpass`
(:func:`mpipe.core.filters.lowpass_block`) while writing ``mouthpiece.npz``. The same
blocks in the same order as the whole-array path: identical outputs, with memory bounded
by a block (a few MB) instead of the take.

References
----------
Chatziioannou & van Walstijn 2012, eq. (16); physics.md F.1, F.2.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from mpipe.core.filters import LOWPASS_BLOCK, lowpass_block
from mpipe.core.signals import NpzStream, blocks, open_npz, signal_moments, signal_range
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.translation import TranslationConfig, TranslationPlan


def translate_to_npz(
    path: str | Path,
    p0,
    u0,
    temperature_c,
    fs: float,
    calibration: Calibration,
    config: TranslationConfig,
    extra: dict | None = None,
) -> dict:
    """Translate a take block by block into ``path`` (``mouthpiece.npz``'s members).

    Parameters
    ----------
    path : str or Path
        The ``.npz`` to write (not atomic: wrap in :func:`mpipe.core.io.write_atomic`).
    p0, u0 : ndarray or DiskArray
        Pressure (Pa) and volume flow (m^3/s) at the reference plane, shape ``(n,)``.
    temperature_c : ndarray or DiskArray
        Effective temperature per sample, degC, shape ``(n,)``.
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        Bore, air and reference plane.
    config : TranslationConfig
        Low-pass and padding.
    extra : dict, optional
        Further (small) members to write.

    Returns
    -------
    dict
        ``p_rms_pa`` and ``u_rms_m3_s``: the standard deviation of the low-passed p and u.
    """
    n = len(p0)
    if len(u0) != n or len(temperature_c) != n:
        raise ValueError(f"p0, u0 and temperature_c must have one length, got {n}, {len(u0)}")
    plan = TranslationPlan.of(fs, calibration, config, *signal_range(temperature_c))
    with tempfile.TemporaryDirectory(dir=Path(path).parent, prefix=".translation.") as scratch:
        raw = Path(scratch) / "p.npz", Path(scratch) / "u.npz"
        with NpzStream(raw[0]) as fp, NpzStream(raw[1]) as fu:
            with fp.signal("x", (n,)) as wp, fu.signal("x", (n,)) as wu:
                for a, b in plan.bounds(n):
                    p, u = plan.block(p0, u0, temperature_c[a:b], a, b)
                    wp.write(p)
                    wu.write(u)
        rms = {}
        with NpzStream(path) as out:
            out.add("fs", np.float64(fs))
            sources = {"p": open_npz(raw[0], 0)["x"], "u": open_npz(raw[1], 0)["x"],
                       "p0": p0, "u0": u0}  # fmt: skip
            for name, x in sources.items():
                with out.signal(name, (n,)) as w:
                    for a, b in blocks(n, LOWPASS_BLOCK):
                        w.write(lowpass_block(x, plan.lowpass, a, b))
            with out.signal("temperature_c", (n,)) as w:
                for a, b in blocks(n):
                    w.write(temperature_c[a:b])
            for name, value in (extra or {}).items():
                out.add(name, value)
    done = open_npz(path)
    rms["p_rms_pa"] = signal_moments(done["p"])[1]
    rms["u_rms_m3_s"] = signal_moments(done["u"])[1]
    return rms
