"""The resynthesis of a take written block by block: the numbers of :func:`resynthesise`.

:func:`resynthesise_to_npz` runs the model of each window as
:func:`mpipe.inversion.output.resynthesis.resynthesise` does (from its history, read from the
take on disk around the window) and drives each window's reed as
:func:`mpipe.inversion.preparation.segments.reed_openings` does, and writes ``p``, ``u`` and ``h``
of
``resynthesis.npz`` in blocks of :data:`mpipe.core.signals.BLOCK` samples: each block
starts as NaN and takes the windows that cross it in the table's order (a later row
overwrites an earlier one where windows overlap, as the whole-array path does). A window
crossing a block edge is run once and kept until the block after it. Memory is bounded by
a block and the windows it holds, not by the take.
"""

from __future__ import annotations

import contextlib
import logging
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import soundfile

from mpipe.core.signals import BLOCK, NpzStream, blocks, open_npz
from mpipe.inversion.fit.history_start import lead_in
from mpipe.inversion.fit.objective import ObjectiveSettings, TargetWindow, run_model
from mpipe.inversion.output.resynthesis import reed_from_row
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.opening import opening
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)


def _window_signals(row, p, u, fs, kernel, config, settings, zero_mean):
    """The window's resynthesised p (Pa), u (m^3/s) and opening h (m); None where absent.

    A window without an error gets a resynthesis, and one whose row makes a reed gets an
    opening: the rules of ``resynthesise`` and ``reed_openings``.
    """
    kernel = kernel(row) if callable(kernel) else kernel  # its note's fingering's bore
    i0, i1 = int(round(row["t_start_s"] * fs)), int(round(row["t_end_s"] * fs))
    out_p = out_u = h = None
    try:
        reed = ReedParameters(**{k: float(row[k]) for k in (*PARAMETER_NAMES, "y_c", "alpha")})
        h = opening(reed, p, fs, i0, i1 - i0)
    except (ValueError, TypeError, KeyError):  # no estimate in this window
        pass
    err = row["error"]
    if not ((isinstance(err, str) and err) or not np.isfinite(row["k"])):
        history = lead_in(p, u, i0, i1 - i0, kernel.n_taps, config.lead_s, fs)
        target = TargetWindow(p[i0:i1], u[i0:i1], *history, fs, zero_mean)
        try:
            reed = reed_from_row(row)
        except ValueError as exc:
            log.warning("window at %.3f s not resynthesised: %s", row["t_start_s"], exc)
        else:
            out = run_model(reed, kernel, target, settings, penalty=np.inf)
            if out.feasible:
                out_p, out_u = out.p, out.u
    return out_p, out_u, None if h is None else np.asarray(h)


def resynthesise_to_npz(
    path: str | Path,
    table: pd.DataFrame,
    p,
    u,
    fs: float,
    kernel: BoreKernel,
    config: InversionConfig,
    zero_mean: bool,
    progress=None,
    block: int = BLOCK,
) -> None:
    """Write ``fs``, ``p``, ``u`` (the resynthesis) and ``h`` (the opening) to ``path``.

    Parameters
    ----------
    path : str or Path
        The ``.npz`` to write (not atomic: wrap in :func:`mpipe.core.io.write_atomic`).
    table : pandas.DataFrame
        Per-window results (rows in time order).
    p, u : ndarray or DiskArray
        Target pressure (Pa) and flow (m^3/s) of the take, only sliced.
    fs : float
        Sample rate, Hz.
    kernel : BoreKernel or callable
        Prepared bore, or ``kernel(row)`` giving each window's (its note's fingering).
    config : InversionConfig
        Start method and filters.
    zero_mean : bool
        Whether the target flow is zero-mean.
    progress : mpipe.core.progress.ProgressBar, optional
        Counted once per window.
    block : int
        Samples per block written.
    """
    n = len(p)
    settings = ObjectiveSettings(
        lead_s=config.lead_s, lowpass=config.lowpass.design(fs) if zero_mean else None
    )
    rows = list(table.iterrows())
    spans = [(int(round(r["t_start_s"] * fs)), int(round(r["t_end_s"] * fs))) for _, r in rows]
    run = (p, u, fs, kernel, config, settings, zero_mean)
    with tempfile.TemporaryDirectory(dir=Path(path).parent, prefix=".resynthesis.") as tmp:
        scratch = [Path(tmp) / f"{name}.npz" for name in NAMES]
        with contextlib.ExitStack() as stack:
            writers = [
                stack.enter_context(stack.enter_context(NpzStream(f)).signal("x", (n,)))
                for f in scratch
            ]
            held: dict[int, tuple] = {}  # windows run, kept while they reach the next block
            for a, b in blocks(n, block):
                bufs = [np.full(b - a, np.nan) for _ in NAMES]
                for j, (i0, i1) in enumerate(spans):
                    if i1 <= a or i0 >= b:
                        continue
                    if j not in held:
                        if progress is not None:
                            progress.update(1)
                        held[j] = _window_signals(rows[j][1], *run)
                    lo, hi = max(i0, a), min(i1, b)
                    for buf, part in zip(bufs, held[j], strict=True):
                        if part is not None:
                            buf[lo - a : hi - a] = part[lo - i0 : hi - i0]
                held = {j: v for j, v in held.items() if spans[j][1] > b}
                for w, buf in zip(writers, bufs, strict=True):
                    w.write(buf)
        with NpzStream(path) as out:
            out.add("fs", np.float64(fs))
            for name, f in zip(NAMES, scratch, strict=True):
                x = open_npz(f, 0)["x"]
                with out.signal(name, (n,)) as w:
                    for a, b in blocks(n, block):
                        w.write(x[a:b])


#: The members of ``resynthesis.npz`` besides ``fs``: pressure (Pa), flow (m^3/s) and the
#: reed's opening (m).
NAMES = ("p", "u", "h")


def write_wav_blocks(path: str | Path, x, fs: float, full_scale: float | None = None) -> None:
    """A float WAV of ``x`` (NaN as 0) scaled by ``full_scale`` (default ``max |x|``), in blocks.

    The numbers of :func:`mpipe.inversion.output.resynthesis.write_wav` (not atomic: wrap in
    :func:`mpipe.core.io.write_atomic`); ``x`` is only sliced.
    """
    n = len(x)
    scale = full_scale
    if not scale:
        peak = max((float(np.max(np.abs(np.nan_to_num(x[a:b])))) for a, b in blocks(n)),
                   default=0.0)  # fmt: skip
        scale = peak or 1.0
    with soundfile.SoundFile(path, "w", int(round(fs)), 1, subtype="FLOAT", format="WAV") as f:
        for a, b in blocks(n):
            f.write(np.nan_to_num(x[a:b]) / scale)


def residual_ratio(p, p_res) -> float | None:
    """``|p - p_res| / |p|`` over the samples where the resynthesis is finite, in blocks."""
    num = den = 0.0
    seen = False
    for a, b in blocks(len(p)):
        x, y = p[a:b], p_res[a:b]
        mask = np.isfinite(y)
        if mask.any():
            seen = True
            num += float(np.sum((x[mask] - y[mask]) ** 2))
            den += float(np.sum(x[mask] ** 2))
    return float(np.sqrt(num) / np.sqrt(den)) if seen else None


def resynthesised_samples(p_res) -> int:
    """Samples where the resynthesis is finite."""
    return int(sum(int(np.isfinite(p_res[a:b]).sum()) for a, b in blocks(len(p_res))))


__all__ = [
    "NAMES",
    "residual_ratio",
    "resynthesise_to_npz",
    "resynthesised_samples",
    "write_wav_blocks",
]
