"""The separation of a take on disk into ``reference.npz``, block by block: separate()'s numbers.

:func:`write_reference` runs the two passes of :func:`mpipe.measurement.separation.separate`
on microphone pressures that stay on disk (:class:`mpipe.core.signals.DiskArray`, shape
``(n, N)``): the first estimates theta block by block (each block's spectra computed when
the estimate reaches it, :func:`mpipe.measurement.separation.stage.estimate`), the second
rebuilds p0 and u0 by overlap-add into a buffer that keeps only the samples later blocks
still reach (:func:`mpipe.measurement.separation.reconstruction.overlap_add_blocks`), each
finished stretch written at once. The same arithmetic in the same order as the whole-array
path, so the same numbers, with memory bounded by a block.
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from mpipe.core.signals import NpzStream, blocks, open_npz
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.reconstruction import overlap_add_blocks
from mpipe.measurement.separation.result import SeparationResult
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import checked_pressures, estimate
from mpipe.measurement.takes import read_take


def separate_take(
    path: str | Path,
    paths,
    calibration: Calibration,
    config: SeparationConfig,
    fs: float | None = None,
    workers: int = 1,
) -> dict:
    """Read a take, put its pressures on disk, and separate it into ``path`` block by block.

    The take is read (:func:`mpipe.measurement.takes.read_take`, at the pipeline's rate
    ``fs`` in Hz), its pressures written to a scratch file beside ``path`` and dropped
    from memory, and :func:`write_reference` reads them back block by block (its blocks'
    estimates on ``workers`` processes).

    Returns
    -------
    dict
        ``separation``: the :class:`SeparationResult` (p0, u0 on disk); ``take``: the
        :class:`mpipe.measurement.takes.Take` without its pressures (an empty array).
    """
    take = read_take(paths, calibration, fs=fs)
    with tempfile.TemporaryDirectory(dir=Path(path).parent, prefix=".pressures.") as scratch:
        pressures = Path(scratch) / "pressures.npz"
        with NpzStream(pressures) as out:
            out.add("x", np.ascontiguousarray(take.pressures))
        n_mics = take.pressures.shape[1]
        # the Take keeps its metadata; its samples are on disk from here on
        take = dataclasses.replace(take, pressures=np.zeros((0, n_mics)))
        x = open_npz(pressures)["x"]
        sep = write_reference(path, x, take.fs, calibration, config, take.band_limit_hz,
                              workers)  # fmt: skip
    return {"separation": sep, "take": take, "n_samples": x.shape[0]}


def write_reference(
    path: str | Path,
    pressures,
    fs: float,
    calibration: Calibration,
    config: SeparationConfig,
    band_limit_hz: float | None = None,
    workers: int = 1,
) -> SeparationResult:
    """Separate a take into ``path``: ``fs``, ``p0``, ``u0``, ``temperature_c`` and theta.

    Parameters
    ----------
    path : str or Path
        The ``.npz`` to write (not atomic: wrap in :func:`mpipe.core.io.write_atomic`).
    pressures : ndarray or DiskArray
        Microphone pressures in Pa, shape ``(n, N)``, only sliced.
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        Geometry, air and microphone positions.
    config : SeparationConfig
        Settings.
    band_limit_hz : float, optional
        Highest frequency the recording holds, Hz.
    workers : int
        Processes the blocks' estimates are spread over (the same numbers with any number).

    Returns
    -------
    SeparationResult
        Its ``p0`` and ``u0`` are the file's members, on disk. Besides them the file holds
        ``temperature_c`` (degC per sample, :meth:`SeparationResult.temperature_track`),
        ``mic_noise_psd``, ``theta_median`` (c m/s, eta, Mach) and, when theta was
        estimated, ``theta_level``, ``theta_level_se`` and ``theta_level_cov``.
    """
    x = checked_pressures(pressures, calibration)
    est = estimate(x, fs, calibration, config, band_limit_hz, workers)
    plan, n = est.plan, x.shape[0]
    table = est.table
    times, temps = table["time_s"].to_numpy(), table["temperature_c"].to_numpy()
    with tempfile.TemporaryDirectory(dir=Path(path).parent, prefix=".separation.") as scratch:
        raw = Path(scratch) / "p0.npz", Path(scratch) / "u0.npz"
        with NpzStream(raw[0]) as fp, NpzStream(raw[1]) as fu:
            with fp.signal("x", (n,)) as wp, fu.signal("x", (n,)) as wu:
                for _, _, chunk in overlap_add_blocks(
                    x, fs, plan.starts, plan.length, est.smooth, est.c_track, plan.geometry,
                    config,
                ):  # fmt: skip
                    wp.write(chunk[:, 0])
                    wu.write(chunk[:, 1])
        with NpzStream(path) as out:
            out.add("fs", np.float64(fs))
            for name, f in zip(("p0", "u0"), raw, strict=True):
                src = open_npz(f, 0)["x"]
                with out.signal(name, (n,)) as w:
                    for a, b in blocks(n):
                        w.write(src[a:b])
            with out.signal("temperature_c", (n,)) as w:
                for a, b in blocks(n):  # SeparationResult.temperature_track, by blocks
                    w.write(np.interp(np.arange(a, b) / fs, times, temps))
            out.add("mic_noise_psd", 2 * est.noise_raw)
            probe = est.result(np.zeros(0), np.zeros(0))  # its outcome is logged here
            th = probe.median_theta()
            out.add("theta_median", np.array([th.c, th.eta, th.mach]))
            if probe.track is not None:
                out.add("theta_level", probe.track.level)
                out.add("theta_level_se", probe.track.level_se)
                if probe.track.level_cov is not None:
                    out.add("theta_level_cov", probe.track.level_cov)
    done = open_npz(path)
    return est.result(done["p0"], done["u0"], log_outcome=False)
