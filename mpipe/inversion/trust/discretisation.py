"""The model's discretisation at its sample rate: the ``rate`` component of the budget.

The model of the paper's Appendix A runs at the inversion's sample rate fs
(``inversion.sample_rate``): the reed by centred differences, its coupling to the flow one
step behind, the bore's reflection function band-limited to fs / 2. A real reed plays in
continuous time, so the parameters that make the model at fs play a recording differ from
the reed's by a bias that shrinks as fs grows. ``benchmarks/bench_rate.py`` measured it:
one steady note played by the same model at 400 kHz on a 200 ms reflection function,
brought to fs as a measurement reaches the inversion and inverted there (six playing
points: two reeds, soft and loud, the shipped bore and the four-hole one in two
fingerings; docs/uncertainty.md, "The model's rate").

Its sign is not the same at every playing point (a soft note's p_m can come out low where
a loud one's comes out high), so it cannot be corrected; it is bounded instead. The
relative bias of quantity q is at most

    b_q(fs) = c_q (F_REF_HZ / fs)^ORDER,

with ORDER and c_q from the measurement (c_q: the largest measured |bias| scaled to
F_REF_HZ). Taken per the GUM as a rectangular distribution on [-b, b] (JCGM 100:2008,
4.3.7), its standard uncertainty is ``u_q = b_q |q| / sqrt(3)``: the column
``<q>_se_rate`` of every window (q's unit), shared by all windows of a take (one rate);
issue 34's budget (``mpipe.inversion.trust.budget``, component ``rate``) combines it into
``<q>_se``.
Below :data:`LOWEST_RATE_HZ` the measurement bounds nothing: a pipeline file setting
``inversion.sample_rate`` lower is refused (:func:`check_model_rate`), and
:func:`rate_errors` of a table made there gives inf (no bound).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

# ORDER and LOWEST_RATE_HZ live in the settings, which check the model's rate.
# ORDER, the order of the bound in 1/fs: the least-squares slope of the largest |bias|
# over the six cases against log(F_REF_HZ / fs), median over the quantities (1.3-1.45
# for one loud note alone). Not the second order of the reed's centred differences
# alone: some part of the scheme errs at first order (which part was not isolated).
# LOWEST_RATE_HZ, the lowest model rate whose bias the measurement bounds: at 22.05 kHz
# mpipe's reflection function misses |Z_in| by its 0.1 dB limit at some kernel
# temperatures (the hard reed's inversion stopped there), so the model is not the one
# validated; 32 kHz is the lowest measured rate where every case ran and the bound held.
from mpipe.inversion.settings import LOWEST_RATE_HZ, ORDER, check_model_rate
from mpipe.inversion.trust.combinations import COMBINATION_NAMES

#: Quantities whose discretisation bias was measured (y_c is fixed unless contact: free,
#: and was not measured: its column stays NaN, the component does not apply).
QUANTITIES = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c", *COMBINATION_NAMES)

#: Reference frequency of the error model, Hz: the band the fit compares (the
#: translation's low-pass cut-off). Neither the playing frequency nor the reed's resonance
#: collapsed the measured biases better (the stiffer reed, f_r 2.76 kHz, had smaller
#: biases than the Table 1 reed's 2.09 kHz; the four-hole bore's xxoo note, whose first
#: resonance is 19 % higher, 0.94 times its xxxx note's at 44.1 kHz, not 1.24 times).
F_REF_HZ = 7250.0
#: c_q of the bound: the largest measured |bias| (fs / F_REF_HZ)^ORDER over the six cases
#: and the fitted rates, rounded up to three digits (the relative bias at fs = F_REF_HZ).
BIAS_CONSTANTS: dict[str, float] = {
    "k": 0.512, "S": 0.763, "y_m": 0.628, "p_m": 0.833, "m": 0.846, "g": 3.97, "lam": 1.22,
    "k_c": 1.85, "p_M": 1.05, "gamma": 0.348, "zeta": 1.33, "f_r": 0.21, "Q_r": 5.12,
}  # fmt: skip
#: Provenance of the constants above: ``bench_rate.py --variants scheme`` (six cases,
#: 400 kHz reference on a 200 ms reflection function; fitted on 22.05, 32, 48, 50, 96 and
#: 100 kHz, 44.1 kHz held out for tests/inversion/trust/test_discretisation.py).
MEASURED_BY = "benchmarks/bench_rate.py --variants scheme"
#: The rates the constants were fitted on, Hz.
FIT_RATES_HZ = (22050.0, 32000.0, 48000.0, 50000.0, 96000.0, 100000.0)


def relative_bound(quantity: str, fs: float) -> float:
    """The bound b_q(fs) on q's relative discretisation bias (inf below the lowest rate).

    Parameters
    ----------
    quantity : str
        One of :data:`QUANTITIES` (another: NaN, not measured).
    fs : float
        Model sample rate, Hz.

    Returns
    -------
    float
        Dimensionless; NaN for a quantity not measured, inf when ``fs`` is below
        :data:`LOWEST_RATE_HZ`.
    """
    if quantity not in BIAS_CONSTANTS:
        return math.nan
    if not fs >= LOWEST_RATE_HZ:
        return math.inf
    return BIAS_CONSTANTS[quantity] * (F_REF_HZ / fs) ** ORDER


def relative_uncertainty(quantity: str, fs: float) -> float:
    """Standard uncertainty of q's relative discretisation bias: b_q(fs) / sqrt(3)."""
    return relative_bound(quantity, fs) / math.sqrt(3.0)


def rate_errors(table: pd.DataFrame, fs_model: float) -> pd.DataFrame:
    """Add the ``rate`` component ``<q>_se_rate`` (q's unit) to every window of a table.

    Parameters
    ----------
    table : pandas.DataFrame
        Windows table holding the estimates ``q``.
    fs_model : float
        Sample rate the model ran at, Hz (the inversion's).

    Returns
    -------
    pandas.DataFrame
        A copy with ``<q>_se_rate = |q| b_q(fs) / sqrt(3)`` for each q of
        :data:`QUANTITIES` in the table (NaN where q is; inf below
        :data:`LOWEST_RATE_HZ`).
    """
    out = table.copy()
    for q in QUANTITIES:
        if q not in out:
            continue
        x = pd.to_numeric(out[q], errors="coerce").to_numpy(dtype=float)
        rel = relative_uncertainty(q, fs_model)
        with np.errstate(invalid="ignore"):
            out[f"{q}_se_rate"] = np.where(np.isnan(x), np.nan, np.abs(x) * rel)
    return out


def fit_bound(rows: pd.DataFrame, quantities, f_ref_hz: float = F_REF_HZ):
    """Fit the bound's order and constants to measured biases (``bench_rate.py``).

    Parameters
    ----------
    rows : pandas.DataFrame
        One row per (case, rate): ``fs`` (Hz) and the relative bias of each quantity.
    quantities : sequence of str
        The quantities to fit.
    f_ref_hz : float
        Reference frequency, Hz.

    Returns
    -------
    order : float
        The least-squares slope of log max-over-cases |bias| against log(f_ref / fs),
        median over the quantities.
    constants : dict
        Per quantity, the largest |bias| (fs / f_ref)^order over the rows: the bound
        holds at every fitted row.
    """
    fs = rows["fs"].to_numpy(dtype=float)
    rates = np.unique(fs)
    slopes = []
    for q in quantities:
        envelope = np.array([np.nanmax(np.abs(rows.loc[fs == r, q])) for r in rates])
        if rates.size >= 2 and np.all(envelope > 0):
            slopes.append(np.polyfit(np.log(f_ref_hz / rates), np.log(envelope), 1)[0])
    order = float(np.median(slopes)) if slopes else math.nan
    scale = (fs / f_ref_hz) ** order
    constants = {q: float(np.nanmax(np.abs(rows[q].to_numpy(float)) * scale)) for q in quantities}
    return order, constants


__all__ = [
    "BIAS_CONSTANTS",
    "F_REF_HZ",
    "LOWEST_RATE_HZ",
    "ORDER",
    "QUANTITIES",
    "check_model_rate",
    "fit_bound",
    "rate_errors",
    "relative_bound",
    "relative_uncertainty",
]
