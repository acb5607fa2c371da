"""The span of a take to invert, counted in samples.

A span is asked for in seconds (``--start``, ``--end``, ``conditioning.edge_s``) and
planned in samples: :func:`span_samples` converts once, :func:`check_span` refuses a span
outside the take or too short for one window before any work.
"""

from __future__ import annotations

import numpy as np


def span_samples(
    n: int, fs: float, edge_s: float, start_s: float | None, end_s: float | None
) -> tuple[int, int]:
    """First and last sample (exclusive) of the span asked for, clipped to the take.

    The span's first sample is its start rounded to the nearest sample, and its length is
    rounded once (with a millionth of a sample of tolerance), not its two ends separately:
    a span of exactly one window (0.40 to 0.42 s for 20 ms) then holds that window at
    every rate, although ``0.42 - 0.40 < 0.02`` in floating point and 0.40 s and 0.42 s
    fall between samples at 93 034 Hz.

    Parameters
    ----------
    n : int
        Samples of the take.
    fs : float
        Sample rate, Hz.
    edge_s : float
        ``conditioning.edge_s``, s: left out at an end not given.
    start_s, end_s : float or None
        Span asked for, s.

    Returns
    -------
    (int, int)
        First sample of the span and the sample after its last.
    """
    first = edge_s if start_s is None else max(start_s, 0.0)
    last = n / fs - edge_s if end_s is None else min(end_s, n / fs)
    first_n = int(round(first * fs))
    length_n = int(np.floor((last - first) * fs + 0.5 + 1e-6))
    return first_n, min(first_n + max(length_n, 0), n)


def check_span(
    n: int, fs: float, edge_s: float, window_s: float, start_s: float | None, end_s: float | None
) -> None:
    """Refuse a span outside the take or too short for one window, saying why.

    Parameters
    ----------
    n : int
        Samples of the take.
    fs : float
        Sample rate, Hz.
    edge_s, window_s : float
        ``conditioning.edge_s`` and ``inversion.window_s``, s.
    start_s, end_s : float or None
        Span asked for, s (None: the take less ``edge_s``).

    Raises
    ------
    ValueError
        Naming the span, the take's length and the setting to change.
    """
    duration = n / fs
    take = f"the take lasts {duration:.3f} s"
    for name, value in (("start", start_s), ("end", end_s)):
        if value is not None and not 0.0 <= value <= duration:
            raise ValueError(f"{name} {value:g} s lies outside the take (0 to {duration:.3f} s)")
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise ValueError(f"end {end_s:g} s is not after start {start_s:g} s ({take})")
    first_n, last_n = span_samples(n, fs, edge_s, start_s, end_s)
    if last_n - first_n >= int(round(window_s * fs)):
        return
    first, last = first_n / fs, last_n / fs
    if start_s is None or end_s is None:
        raise ValueError(
            f"conditioning.edge_s = {edge_s:g} s at each end leaves {max(last - first, 0):.3f} s "
            f"of the {duration:.3f} s take, less than one window (inversion.window_s = "
            f"{window_s:g} s); expected edge_s below {max((duration - window_s) / 2, 0):.3g} s"
        )
    raise ValueError(
        f"the span {first:g}-{last:g} s is shorter than one window (inversion.window_s = "
        f"{window_s:g} s; {take})"
    )
