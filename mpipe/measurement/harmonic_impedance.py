"""A played note's impedance at its harmonics, with its uncertainty, tested against the theory.

A played note measures ``Z = P / U`` only at its harmonics. Each harmonic is read on short
frames of :data:`FRAME_PERIODS` periods (Hann, half-overlapping): a Hann frame of exactly
m periods puts its zeros on every other harmonic and on the half-harmonics, so no line
leaks into another, on a frame grid that does not depend on the sample rate (the Welch
bins of the take did: the bin nearest a harmonic moves with the rate). Each frame's f0 is
refined on its own (the pitch of a note drifts and wavers), and the theory is taken at
each frame's frequencies.

The comparison is made on the entry reflection coefficient ``R = (z - 1) / (z + 1)``
(``z = Z / Z0``), which stays well conditioned where ``z`` is small: near an
anti-resonance a small absolute error in P is a large relative error in z (1.5 dB and
40 deg at harmonic 6 of a correct take), while ``|dR| = 2 |dz| / |1 + z|^2`` is not
amplified; a wrong bore, temperature or fingering turns R by the same angle at every
harmonic (the round trip's phase ``2 k L``).

Each harmonic's error ``dR`` is weighed against its standard uncertainty, the root sum of
squares of: the measurement's (the weighted scatter of the frames' ratios about their mean,
per independent frame), the theory's sensitivity to the air temperature (+-
:data:`TEMPERATURE_SE_C`) and to the bore's length (+- :data:`LENGTH_SE_M`), and a
model-form floor :data:`FLOOR_R`. With ``dR`` a circular complex Gaussian of that variance,
``|dR|^2 / sigma^2`` is exponential: one harmonic fails when it exceeds ``ln(2 H / alpha)``
(Bonferroni over the H harmonics compared, half the false-alarm rate ``alpha``), and the
note fails when the sum over its harmonics exceeds the Gamma(H) quantile at ``alpha / 2``
(an error shared by every harmonic, each within its own bound).

References
----------
Bendat & Piersol, Random Data, 4th ed., sections 9.2-9.3 (frequency-response estimates);
physics.md F.3.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from mpipe.core.harmonic_fit import (
    amplitudes,
    centred_gram,
    centred_projection,
    harmonic_dft,
    harmonic_synthesis,
)

#: Periods of the note in one frame: a Hann frame of m >= 2 periods has zeros at every other
#: harmonic (offsets of m bins) and, for even m, at the half-harmonics (the noise probes).
FRAME_PERIODS = 4
#: Fewest frames for a harmonic's uncertainty (the scatter of fewer says little).
MIN_FRAMES = 4
#: A frame holds a harmonic when the flow's line is this many times (power) the flow at the
#: half-harmonics beside it (20 dB: the rule of the Welch bins before).
LINE_RATIO = 100.0
#: Standard uncertainty of the theory's air temperature, degC.
TEMPERATURE_SE_C = 1.0
#: Standard uncertainty of the bore's acoustic length (its end corrections, the measured
#: geometry), m.
LENGTH_SE_M = 1e-3
#: Model-form floor of |dR| (the two theories of one bore differ by up to 0.011 in R at
#: the first ten harmonics, benchmarks/foreign_sim.py's geometries), dimensionless.
FLOOR_R = 0.02
#: Columns of the harmonics table.
COLUMNS = ("harmonic", "frequency_hz", "error_db", "error_deg", "coherence", "compared", "frames",
           "delta_r", "sigma_r", "sigma_measured_r", "sigma_theory_r", "z_score")  # fmt: skip


def reflection(z: np.ndarray) -> np.ndarray:
    """Entry reflection coefficient ``(z - 1) / (z + 1)`` of a normalised impedance."""
    z = np.asarray(z, dtype=complex)
    return (z - 1.0) / (z + 1.0)


def frame_lines(
    p: np.ndarray, u: np.ndarray, fs: float, f0: float, n_harmonics: int, fmax_hz: float
) -> dict:
    """The note's lines on half-overlapping frames of :data:`FRAME_PERIODS` periods.

    Parameters
    ----------
    p, u : ndarray
        Pressure (Pa) and flow (m^3/s) of the note.
    fs : float
        Sample rate, Hz.
    f0 : float
        The note's playing frequency, Hz (each frame's is refined about it).
    n_harmonics : int
        Harmonics read (those up to ``fmax_hz`` and below ``0.45 fs``).
    fmax_hz : float
        Top of the harmonics read, Hz.

    Returns
    -------
    dict
        ``f0`` (n_frames,) Hz, each frame's refined playing frequency; ``harmonics`` (H,)
        orders; ``P``, ``U`` (H, n_frames) complex amplitudes (Pa, m^3/s; a least-squares
        fit of every line at once, ``x = Re(a exp(j 2 pi h f t))``); ``U_half`` (H,
        n_frames) the rms flow at ``(h +- 1/2) f0``.
        Empty arrays when the note holds fewer than :data:`MIN_FRAMES` frames.

    Notes
    -----
    Every frame is fitted at once (:func:`_batched_lines`: the closed-form Gram matrix and
    the DFT at the harmonics of :mod:`mpipe.core.harmonic_fit`); a frame whose design is
    degenerate sends the note to the plain reference, a least-squares solve per frame
    (:func:`_reference_lines`), which the batched fit equals to rounding.
    """
    h, frames, f_frames, fitted = _framed(p, u, fs, f0, n_harmonics, fmax_hz)
    if frames is None:
        empty = np.zeros((h.size, 0), complex)
        return {"f0": np.zeros(0), "harmonics": h, "P": empty, "U": empty, "U_half": empty}
    try:
        lines = _batched_lines(frames, f_frames, fs, fitted, h.size)
    except np.linalg.LinAlgError:  # a degenerate design: the rank-revealing solve per frame
        lines = _reference_lines(frames, f_frames, fs, fitted, h.size)
    return {"f0": f_frames, "harmonics": h, **lines}


def _framed(p, u, fs, f0, n_harmonics, fmax_hz) -> tuple:
    """The harmonics read, the frames (F, 2, n) without their means, each frame's f0, Hz.

    Also the orders fitted: every line up to 2 fmax (or 0.45 fs) is fitted at once, so
    none leaks into another (a weak even harmonic beside a loud odd one: a Hann
    projection's leakage of 1e-3 was 10 % of it once the frame held not exactly four
    periods). The frames are None when the note holds fewer than :data:`MIN_FRAMES`.
    """
    h = np.arange(1, n_harmonics + 1)
    h = h[(h * f0 <= fmax_hz) & (h * f0 < 0.45 * fs)]
    n = int(round(FRAME_PERIODS * fs / f0))
    hop = max(n // 2, 1)
    size = np.size(p)
    starts = np.arange(0, size - n + 1, hop) if size >= n else np.zeros(0, int)
    if starts.size < MIN_FRAMES or h.size == 0:
        return h, None, None, None
    signals = np.stack([np.asarray(p, dtype=float), np.asarray(u, dtype=float)])
    frames = np.lib.stride_tricks.sliding_window_view(signals, n, axis=1)[:, starts]
    frames = np.swapaxes(frames - frames.mean(axis=-1, keepdims=True), 0, 1)
    t = np.arange(n) / fs
    f_frames = _refine(frames[:, 0] * np.hanning(n), t, f0, h, hop / fs)
    fitted = np.arange(1, max(int(min(0.45 * fs, 2.0 * fmax_hz) / f0), int(h[-1])) + 1)
    return h, frames, f_frames, fitted


def _batched_lines(
    frames: np.ndarray, f_frames: np.ndarray, fs: float, fitted: np.ndarray, n_read: int
) -> dict:
    """Every frame's lines at once: ``P``, ``U`` and ``U_half`` of :func:`frame_lines`.

    Parameters
    ----------
    frames : ndarray
        Pressure and flow frames without their means, shape (F, 2, n): Pa, m^3/s.
    f_frames : ndarray
        Each frame's fundamental, Hz, shape (F,).
    fs : float
        Sample rate, Hz.
    fitted : ndarray
        Orders fitted, 1..K.
    n_read : int
        H, the first orders returned.

    Raises ``numpy.linalg.LinAlgError`` when a frame's Gram matrix is not positive
    definite.
    """
    n, k = frames.shape[-1], fitted.size
    w = 2 * np.pi * f_frames / fs  # rad per sample
    # the centred design's two blocks, each frame's Cholesky check (far from rank deficient:
    # the normal equations hold) and solve, for p and u together
    coef = []
    blocks = zip(centred_gram(n, w, k), centred_projection(frames, w[:, None], k), strict=True)
    for gram, rhs in blocks:
        np.linalg.cholesky(gram)
        coef.append(np.swapaxes(np.linalg.solve(gram, np.swapaxes(rhs, -1, -2)), -1, -2))
    constant, amp = amplitudes(coef[0], coef[1], w[:, None], n)  # (F, 2), (F, 2, K)
    # the flow between the lines: the residual's Hann projection at h +- 1/2, as an
    # amplitude (a line of amplitude a projects to a sum(w) / 2)
    fit_u = constant[:, 1:] + harmonic_synthesis(amp[:, 1], w, fitted, n)
    window = np.hanning(n)
    h = np.arange(1, n_read + 1)
    sides = np.concatenate([2 * h + 1, 2 * h - 1])  # (h +- 1/2) w = (2 h +- 1) w / 2
    probe = harmonic_dft((frames[:, 1] - fit_u) * window, w / 2, sides)
    probe = 2 * np.abs(probe) / window.sum()
    u_half = np.sqrt(0.5 * (probe[:, :n_read] ** 2 + probe[:, n_read:] ** 2))
    # a line 80 dB under the frame's strongest is rounding, not a harmonic played
    u_half = np.maximum(u_half, 1e-4 * np.abs(amp[:, 1]).max(axis=1, keepdims=True))
    return {"P": amp[:, 0, :n_read].T, "U": amp[:, 1, :n_read].T, "U_half": u_half.T}


def _reference_lines(
    frames: np.ndarray, f_frames: np.ndarray, fs: float, fitted: np.ndarray, n_read: int
) -> dict:
    """:func:`_batched_lines` frame by frame on the explicit design (``numpy.linalg.lstsq``).

    The plain reference (the loop :func:`frame_lines` ran before its frames were batched)
    and the fallback of a degenerate design.
    """
    n_frames, n = frames.shape[0], frames.shape[-1]
    t, window = np.arange(n) / fs, np.hanning(n)
    pa = np.empty((n_read, n_frames), complex)
    ua = np.empty((n_read, n_frames), complex)
    u_half = np.empty((n_read, n_frames))
    h = np.arange(1, n_read + 1)
    for j, f in enumerate(f_frames):
        ps, us = frames[j]
        e = np.exp(2j * np.pi * np.outer(t, fitted * f))
        design = np.hstack([e.real, e.imag, np.ones((n, 1))])
        coef, *_ = np.linalg.lstsq(design, np.column_stack([ps, us]), rcond=None)
        k = fitted.size
        amp = coef[:k] - 1j * coef[k : 2 * k]
        pa[:, j], ua[:, j] = amp[:n_read, 0], amp[:n_read, 1]
        rest = (us - design @ coef[:, 1]) * window
        sides = np.concatenate([h + 0.5, h - 0.5]) * f
        probe = np.exp(-2j * np.pi * np.outer(sides, t)) @ rest
        probe = 2 * np.abs(probe) / window.sum()
        u_half[:, j] = np.sqrt(0.5 * (probe[:n_read] ** 2 + probe[n_read:] ** 2))
        u_half[:, j] = np.maximum(u_half[:, j], 1e-4 * np.abs(amp[:, 1]).max())
    return {"P": pa, "U": ua, "U_half": u_half}


def _refine(frames: np.ndarray, t: np.ndarray, f0: float, h: np.ndarray, dt: float) -> np.ndarray:
    """Each frame's f0, Hz: from the phase advance of the first harmonics between frames.

    Projected at the nominal ``h f0``, a line at ``h f`` advances by ``2 pi h (f - f0) dt``
    more than the nominal between frames ``dt`` apart (unambiguous for ``|f - f0| < f0 /
    (2 h f0 dt)``, +-12 % at three harmonics and two periods); the pairs' offsets, weighted
    by the lines' power, are averaged onto the frames.
    """
    hs = h[: min(h.size, 3)]
    x = frames @ np.exp(-2j * np.pi * np.outer(t, hs * f0))  # (frames, harmonics)
    if x.shape[0] < 2:
        return np.full(x.shape[0], f0)
    rot = x[1:] * np.conj(x[:-1]) * np.exp(-2j * np.pi * hs * f0 * dt)
    offsets = np.angle(rot) / (2 * np.pi * hs * dt)  # f - f0 per pair and harmonic
    weights = np.abs(rot) * hs**2  # a higher harmonic's phase reads f more finely
    pair = np.sum(weights * offsets, axis=1) / np.maximum(np.sum(weights, axis=1), 1e-300)
    pair = np.clip(pair, -0.05 * f0, 0.05 * f0)
    per_frame = np.concatenate([[pair[0]], 0.5 * (pair[1:] + pair[:-1]), [pair[-1]]])
    return f0 + per_frame


def compare_harmonics(lines: dict, theory, alpha: float) -> tuple[pd.DataFrame, list[str]]:
    """Each harmonic's ``dR`` against its uncertainty, and the failures of the two tests.

    Parameters
    ----------
    lines : dict
        :func:`frame_lines`'s output.
    theory : callable
        ``theory(freqs_hz, dT_c, length_scale)`` -> normalised impedance ``Z / Z0`` at the
        air temperature shifted by ``dT_c`` degC and the frequencies scaled by
        ``length_scale`` (a longer bore plays its impedance at lower frequencies); its
        ``z0`` (Pa s/m^3) normalises the measured ratio and ``length_m`` is the bore's.
    alpha : float
        False-alarm rate of the note's verdict (both tests together).

    Returns
    -------
    table : pandas.DataFrame
        One row per harmonic, columns :data:`COLUMNS`.
    failures : list of str
    """
    f_frames, hs = lines["f0"], lines["harmonics"]
    rows = []
    if f_frames.size:
        # the theory in a few vectorised calls: every frame's harmonics, then the
        # sensitivities at each harmonic's mean frequency
        z_th = theory(np.outer(hs, f_frames).ravel(), 0.0, 1.0).reshape(hs.size, -1)
        w = np.abs(lines["U"]) ** 2
        held = _held(lines["U"], lines["U_half"])
        w = np.where(held.sum(axis=1, keepdims=True) >= MIN_FRAMES, w * held, w)
        f_mean = np.sum(w * np.outer(hs, f_frames), axis=1) / np.maximum(w.sum(axis=1), 1e-300)
        scale = 1.0 + LENGTH_SE_M / theory.length_m
        shifted = [reflection(theory(f_mean, d_t, k)) for d_t, k in
                   ((TEMPERATURE_SE_C, 1.0), (-TEMPERATURE_SE_C, 1.0), (0.0, scale),
                    (0.0, 1.0 / scale))]  # fmt: skip
        s_theory = np.hypot(np.hypot(np.abs(shifted[0] - shifted[1]) / 2,
                                     np.abs(shifted[2] - shifted[3]) / 2), FLOOR_R)  # fmt: skip
    for i, h in enumerate(hs):
        if not f_frames.size:
            rows.append([int(h), math.nan, math.nan, math.nan, math.nan, False, 0]
                        + [math.nan] * 5)  # fmt: skip
            continue
        rows.append(_one_harmonic(int(h), f_mean[i], lines["P"][i], lines["U"][i],
                                  lines["U_half"][i], z_th[i], float(s_theory[i]),
                                  theory.z0))  # fmt: skip
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    return table, _failures(table, alpha)


def _one_harmonic(h, f_mean, pa, ua, u_half, z_th, s_theory, z0) -> list:
    """One row of the harmonics table (see :data:`COLUMNS`); ``z_th`` per frame.

    Only the frames where the flow's line stands :data:`LINE_RATIO` above its half-harmonic
    neighbours count (an attack, a release, a gap or another note's frames do not), and the
    harmonic is compared from :data:`MIN_FRAMES` of them on.
    """
    held = _held(ua, u_half)
    line = int(held.sum()) >= MIN_FRAMES
    if line:
        pa, ua, z_th = pa[held], ua[held], z_th[held]
    w = np.abs(ua) ** 2
    wsum = float(np.sum(w))
    if not wsum > 0:
        return [h, f_mean, math.nan, math.nan, math.nan, False, ua.size] + [math.nan] * 5
    cross = np.sum(np.conj(ua) * pa)
    z_me = complex(cross / wsum / z0)
    z_eff = complex(np.sum(w * z_th) / wsum)  # the theory weighted as the estimate weighs
    coherence = float(abs(cross) ** 2 / max(wsum * float(np.sum(np.abs(pa) ** 2)), 1e-300))
    delta = complex(reflection(z_me) - reflection(z_eff))
    # the measurement: the frames' ratios about the theory's, weighted as the estimate, per
    # independent frame (half-overlapping Hann frames: about half as many independent ones)
    n = ua.size
    d = pa / np.where(ua == 0, 1e-300, ua) / z0 - z_th
    d = d - np.sum(w * d) / wsum
    var_z = float(np.sum(w**2 * np.abs(d) ** 2) / wsum**2) * 2.0 * n / max(n - 1, 1)
    s_meas = 2.0 / abs(1.0 + z_me) ** 2 * math.sqrt(var_z)  # |dR / dz| times sigma_z
    sigma = math.hypot(s_meas, s_theory)
    return [h, f_mean, 20 * math.log10(abs(z_me) / abs(z_eff)),
            math.degrees(np.angle(z_me / z_eff)), coherence, bool(line), n, abs(delta),
            sigma, s_meas, s_theory, abs(delta) / sigma]  # fmt: skip


def _held(ua: np.ndarray, u_half: np.ndarray) -> np.ndarray:
    """The frames that hold a harmonic: its flow line :data:`LINE_RATIO` above its sides."""
    return np.abs(ua) ** 2 > LINE_RATIO * np.abs(u_half) ** 2


def _failures(table: pd.DataFrame, alpha: float) -> list[str]:
    """The per-harmonic (Bonferroni) and the note's summed test, each at ``alpha / 2``."""
    used = table[table["compared"].astype(bool)]
    if not len(used):
        return []
    n = len(used)
    limit = math.sqrt(math.log(2 * n / alpha))  # P(|dR| > limit sigma) = alpha / (2 n)
    out = []
    for _, r in used[used["z_score"] > limit].iterrows():
        out.append(
            f"harmonic {int(r.harmonic)} at {r.frequency_hz:.1f} Hz: reflection coefficient "
            f"off by {r.delta_r:.3f} = {r.z_score:.1f} sigma (limit {limit:.2f} sigma, "
            f"false alarm {alpha:g} per note; {r.error_db:+.2f} dB, {r.error_deg:+.1f} deg "
            "in Z)"
        )
    total = float(np.sum(used["z_score"].to_numpy(float) ** 2))
    bound = float(stats.gamma.isf(alpha / 2, n))
    if not out and total > bound:
        out.append(
            f"the {n} harmonics together: sum of squared errors {total:.1f} > {bound:.1f} "
            f"(Gamma({n}) at {alpha / 2:g}): an error shared by every harmonic"
        )
    return out


__all__ = ["COLUMNS", "compare_harmonics", "frame_lines", "reflection"]
