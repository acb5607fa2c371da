"""Relative calibration tables H_c of the microphones: the CSV format, read and applied.

Format
------
CSV with the header ``frequency_hz,magnitude,phase_deg`` (lines starting with ``#`` are
comments), strictly increasing frequencies in Hz, magnitude > 0 (dimensionless), phase in
degrees. Magnitude and unwrapped phase are interpolated linearly in frequency; outside the
table the end values are held, but the table must cover the analysis band. The correction
is applied to the whole take with one zero-padded FFT; the DC and Nyquist bins, which must
stay real, are divided by the magnitude only.

References
----------
Chung & Blaser 1980, JASA 68(3):907-913 (relative calibration by switching); physics.md E.6.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import scipy.fft
import scipy.signal

from mpipe.core.errors import UserError
from mpipe.measurement.take_checks import BAND_HZ, BAND_LOW_HZ

# Zero padding of the calibration FFT at each end, s.
_PAD_S = 0.05

_CSV_COLUMNS = ("frequency_hz", "magnitude", "phase_deg")


def read_mic_calibration(
    path: str | Path, band: tuple[float, float] | None = (BAND_LOW_HZ, BAND_HZ)
) -> tuple[np.ndarray, np.ndarray]:
    """Read a relative microphone calibration table (physics.md E.6).

    Parameters
    ----------
    path : str or Path
        CSV with the header ``frequency_hz,magnitude,phase_deg``.
    band : (float, float), optional
        Frequencies in Hz the table must cover; None skips the check.

    Returns
    -------
    freqs : ndarray
        Frequencies, Hz, strictly increasing.
    H : ndarray
        Complex H_c (dimensionless), with the phase unwrapped along frequency.

    Raises
    ------
    UserError
        Naming the file and line for a missing file, a wrong header, a non-numeric or
        non-finite value, non-increasing frequencies, a magnitude <= 0, or a table that does
        not cover ``band``.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise UserError(f"{path}: cannot read microphone calibration: {exc.strerror}") from None
    rows = []
    header = None
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        if header is None:
            header = tuple(c.strip().lower() for c in row)
            if header != _CSV_COLUMNS:
                raise UserError(
                    f"{path}: line {lineno}: expected the header {','.join(_CSV_COLUMNS)}, "
                    f"got {','.join(row)}"
                )
            continue
        if len(row) != 3:
            raise UserError(f"{path}: line {lineno}: expected 3 values, got {len(row)}")
        try:
            values = [float(v) for v in row]
        except ValueError:
            raise UserError(
                f"{path}: line {lineno}: expected numbers, got {','.join(row)}"
            ) from None
        if not all(math.isfinite(v) for v in values):
            raise UserError(f"{path}: line {lineno}: non-finite value")
        if values[1] <= 0:
            raise UserError(f"{path}: line {lineno}: magnitude must be > 0, got {values[1]:g}")
        rows.append(values)
    if header is None:
        raise UserError(f"{path}: empty; expected the header {','.join(_CSV_COLUMNS)}")
    if len(rows) < 2:
        raise UserError(f"{path}: expected at least two rows of data, got {len(rows)}")
    table = np.asarray(rows)
    freqs = table[:, 0]
    if np.any(np.diff(freqs) <= 0):
        i = int(np.flatnonzero(np.diff(freqs) <= 0)[0])
        raise UserError(
            f"{path}: frequencies must increase strictly ({freqs[i + 1]:g} Hz follows "
            f"{freqs[i]:g} Hz)"
        )
    if band is not None and (freqs[0] > band[0] or freqs[-1] < band[1]):
        raise UserError(
            f"{path}: covers {freqs[0]:g}-{freqs[-1]:g} Hz, which does not include the band "
            f"{band[0]:g}-{band[1]:g} Hz"
        )
    phase = np.unwrap(np.deg2rad(table[:, 2]))
    return freqs, table[:, 1] * np.exp(1j * phase)


#: Taps of the relative calibration's inverse filter (1.49 s at 44.1 kHz): the table's
#: piecewise-linear interpolation and its ends make a response whose tails decay slowly.
RESPONSE_TAPS = 1 << 16
#: Output samples per block of :func:`divide_response_blocks`.
RESPONSE_BLOCK = 1 << 18


def _interpolated(f: np.ndarray, freqs: np.ndarray, h: np.ndarray, even: bool) -> np.ndarray:
    """H at ``f`` (magnitude and unwrapped phase interpolated), real at DC and Nyquist."""
    mag = np.interp(f, freqs, np.abs(h))
    phase = np.interp(f, freqs, np.unwrap(np.angle(h)))
    resp = mag * np.exp(1j * phase)
    # DC and Nyquist of a real signal are real: divide them by the magnitude only
    resp[0] = mag[0]
    if even:
        resp[-1] = mag[-1]
    return resp


def inverse_response(fs: float, freqs: np.ndarray, h: np.ndarray, taps: int = RESPONSE_TAPS):
    """The FIR dividing by H: ``taps`` samples (even), centred (lag 0 at ``taps // 2``)."""
    f = np.arange(taps // 2 + 1) * fs / taps
    g = scipy.fft.irfft(1.0 / _interpolated(f, freqs, h, True), taps)
    return np.roll(g, taps // 2)


def divide_response_blocks(
    x, fs: float, freqs: np.ndarray, h: np.ndarray, block: int = RESPONSE_BLOCK
) -> np.ndarray:
    """:func:`divide_response` as a filter, a block at a time (memory bounded by a block).

    Each block of output is the block's input and half the filter on either side (zeros
    beyond the signal's ends) convolved with :func:`inverse_response`. It differs from the
    one FFT of the whole signal by at most 1e-4 of its RMS: no more than the whole-signal
    path differs from itself when the take is a little shorter (its frequency grid, and so
    its filter, follows the take's length).
    """
    g = inverse_response(fs, freqs, h)
    half = g.size // 2
    n = len(x)
    out = np.empty(n)
    for a in range(0, n, block):
        b = min(a + block, n)
        lo, hi = max(a - half, 0), min(b + half, n)
        seg = np.zeros(b - a + 2 * half)
        seg[lo - (a - half) : hi - (a - half)] = x[lo:hi]
        # y[i] = sum_m g[m + half] x[i - m]: the 'valid' part, shifted by the centring
        out[a:b] = scipy.signal.fftconvolve(seg, g, mode="valid")[1 : 1 + b - a]
    return out


def divide_response(x: np.ndarray, fs: float, freqs: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Divide the spectrum of ``x`` by the interpolated H (magnitude, unwrapped phase)."""
    n = x.size
    pad = int(_PAD_S * fs)
    n_fft = scipy.fft.next_fast_len(n + 2 * pad, real=True)
    spec = scipy.fft.rfft(x, n_fft)
    f = np.arange(spec.size) * fs / n_fft
    resp = _interpolated(f, freqs, h, n_fft % 2 == 0)
    return scipy.fft.irfft(spec / resp, n_fft)[:n]
