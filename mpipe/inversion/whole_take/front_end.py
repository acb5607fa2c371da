"""What the front end estimated, for the inversion to propagate its errors.

The wave separation's take-level theta (temperature, losses eta, Mach number, position
correction of the middle microphone), its standard errors and covariance, and the
reference-plane signals it was translated from: the inversion moves each parameter by its
SE and follows the change of the mouthpiece signals into its estimates
(:mod:`mpipe.inversion.whole_take.frontend_joint`,
:mod:`mpipe.inversion.whole_take.shared_errors`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from mpipe.inversion.whole_take.frontend_propagation import FRONTEND_NAMES
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.translation import TranslationConfig

#: The front end's take-level theta in a signals file: value, SEs, covariance.
LEVEL_KEYS = ("theta_level", "theta_level_se", "theta_level_cov")
#: The mouthpiece signals' noise in a signals file (:func:`mpipe.measurement.translation
#: .mouthpiece_noise`): frequencies, the two spectra, their cross-spectrum.
NOISE_KEYS = ("u_noise_freq_hz", "p_noise_psd", "u_noise_psd", "pu_noise_csd")


@dataclass(frozen=True)
class MouthpieceNoise:
    """The noise of the mouthpiece pressure and flow: one stationary two-channel process.

    The microphones' sensor noise carried through the separation and the translation
    (:func:`mpipe.measurement.translation.mouthpiece_noise`): its spectra and their
    cross-spectrum, one-sided.

    Attributes
    ----------
    freqs : ndarray
        Frequencies, Hz, 0 to fs/2.
    s_pp : ndarray
        Pressure's PSD, Pa^2/Hz.
    s_uu : ndarray
        Flow's PSD, (m^3/s)^2/Hz.
    s_pu : ndarray
        Cross-spectrum ``E[P conj(U)]``, Pa m^3/s / Hz (complex).
    """

    freqs: np.ndarray
    s_pp: np.ndarray
    s_uu: np.ndarray
    s_pu: np.ndarray

    @classmethod
    def of(cls, mouthpiece: Mapping) -> MouthpieceNoise | None:
        """The noise of a signals file's :data:`NOISE_KEYS`; None when one is missing."""
        if not all(k in mouthpiece for k in NOISE_KEYS):
            return None
        f, pp, uu, pu = (np.asarray(mouthpiece[k]) for k in NOISE_KEYS)
        return cls(f.astype(float), pp.astype(float), uu.astype(float), pu.astype(complex))

    def draw(self, n: int, fs: float, rng: np.random.Generator, k: int = 1):
        """``k`` realisations of ``n`` samples at ``fs`` Hz: pressure (Pa), flow (m^3/s).

        Drawn in the frequency domain on M samples, the power of two at or above 2 n: at
        each DFT bin the two channels' coefficients have the covariance ``(M fs / 2)
        [[S_pp, S_pu], [conj S_pu, S_uu]]``, that of a stationary process of those one-sided
        spectra; the first n samples are returned, so the circular draw's wrap lies outside
        them (drawn on the next power of two of n instead, the flow's low-frequency noise
        tied a window's start to its end and the short take's p_m bars came out 1.48 times
        too narrow). The mean (DC) and Nyquist bins are left empty, and so is every bin
        above the last where a spectrum is not zero (the translation's low-pass ends the
        mouthpiece noise near 8.5 kHz: at 100 kHz five sixths of the bins, whose normal
        draws were most of the cost). Returns two ``(k, n)`` arrays.
        """
        m = 1 << max(int(2 * n - 1).bit_length(), 1)
        l11, l21, l22 = self._factors(m, fs)
        shape = (2, k, l11.size)
        # single precision: a draw of the noise needs no more, and costs half
        z = rng.standard_normal(shape, dtype=np.float32) + 1j * rng.standard_normal(
            shape, dtype=np.float32
        )
        xp, xu = l11 * z[0], l21 * z[0] + l22 * z[1]
        out = (sfft.irfft(x, m, axis=-1)[:, :n].astype(float) for x in (xp, xu))
        return tuple(out)

    def _factors(self, m: int, fs: float):
        """The per-bin Cholesky factor of the two channels' DFT covariance, length m.

        Its bins up to the last one not zero (of the m // 2 + 1). Kept on the instance for
        each ``(m, fs)``: the windows of a take share it.
        """
        cache = self.__dict__.setdefault("_factor_cache", {})
        if (m, fs) not in cache:
            cache[(m, fs)] = self._factors_at(m, fs)
        return cache[(m, fs)]

    def _factors_at(self, m: int, fs: float):
        """:meth:`_factors`, computed (each /sqrt(2): the draws' unit complex normals)."""
        f = np.fft.rfftfreq(m, 1.0 / fs)
        scale = 0.5 * m * fs
        pp = scale * np.interp(f, self.freqs, self.s_pp)
        uu = scale * np.interp(f, self.freqs, self.s_uu)
        pu = scale * (np.interp(f, self.freqs, self.s_pu.real)
                      + 1j * np.interp(f, self.freqs, self.s_pu.imag))  # fmt: skip
        l11 = np.sqrt(np.maximum(pp, 0.0))
        l21 = np.where(l11 > 0, np.conj(pu) / np.where(l11 > 0, l11, 1.0), 0.0)
        l22 = np.sqrt(np.maximum(uu - np.abs(l21) ** 2, 0.0))  # the coherence at most one
        out = []
        for x in (l11, l21, l22):
            x = x / np.sqrt(2.0)
            x[0] = 0.0
            x[-1] = 0.0
            out.append(x.astype(np.complex64 if np.iscomplexobj(x) else np.float32))
        live = np.flatnonzero((np.abs(out[0]) > 0) | (np.abs(out[2]) > 0))
        top = int(live[-1]) + 1 if live.size else 1  # the bins above are zero: not drawn
        return tuple(x[:top] for x in out)


@dataclass(frozen=True)
class FrontEnd:
    """What the front end estimated, to propagate its errors.

    Attributes
    ----------
    p0, u0 : ndarray
        Pressure (Pa) and flow (m^3/s) at the reference plane, as translated.
    temperature_c : ndarray or float
        The temperature the translation used, degC (per sample or one value).
    level : ndarray
        Shape ``(4,)``: the take-level theta (degC, eta, Mach, position correction m).
    level_se : ndarray
        Shape ``(4,)``: its standard errors (0: held, not estimated).
    band_hz : float
        Highest frequency the separation passes, Hz.
    translation : TranslationConfig
        The translation's settings.
    level_cov : ndarray or None
        Shape ``(4, 4)``: the covariance of ``level`` (None: not known, the parameters are
        then taken as independent).
    noise : MouthpieceNoise or None
        The mouthpiece signals' noise (None: not known).
    """

    p0: np.ndarray
    u0: np.ndarray
    temperature_c: np.ndarray | float
    level: np.ndarray
    level_se: np.ndarray
    band_hz: float
    translation: TranslationConfig
    level_cov: np.ndarray | None = None
    noise: MouthpieceNoise | None = None

    def correlation(self, names) -> np.ndarray:
        """The correlation matrix of the named parameters' errors (of :data:`FRONTEND_NAMES`).

        From ``level_cov``; the identity where it is not known or does not match
        ``level_se`` (a file written with other SEs). Two parameters moved each by its SE
        shift the mouthpiece signals, and with them every estimate, by ``d_j`` and ``d_k``;
        the estimate's variance from the front end is ``sum_jk d_j R_jk d_k``, not the sum of
        squares: the temperature's and the losses' errors correlate (both set the waves'
        propagation) and their effects on the take's temperature have opposite signs.
        """
        idx = [FRONTEND_NAMES.index(n) for n in names]
        eye = np.eye(len(idx))
        cov = self.level_cov
        if cov is None or np.shape(cov) != (len(FRONTEND_NAMES),) * 2 or not idx:
            return eye
        cov = np.asarray(cov, float)[np.ix_(idx, idx)]
        se = np.asarray(self.level_se, float)[idx]
        if not (np.all(np.isfinite(cov)) and np.all(se > 0)):
            return eye
        if not np.allclose(np.sqrt(np.maximum(np.diag(cov), 0.0)), se, rtol=1e-6):
            return eye
        r = cov / np.outer(se, se)
        np.fill_diagonal(r, 1.0)
        return np.clip(0.5 * (r + r.T), -1.0, 1.0)

    @classmethod
    def of(
        cls, mouthpiece: Mapping, separation: SeparationConfig, translation: TranslationConfig
    ) -> FrontEnd | None:
        """The front end of a mouthpiece file's arrays; None without theta's SEs.

        ``mouthpiece`` holds ``p0, u0, temperature_c, theta_level, theta_level_se`` and, when
        the separation wrote it, ``theta_level_cov``.
        """
        if "theta_level_se" not in mouthpiece:
            return None
        m = mouthpiece
        cov = m["theta_level_cov"] if "theta_level_cov" in m else None
        return cls(m["p0"], m["u0"], m["temperature_c"], np.asarray(m["theta_level"], float),
                   np.asarray(m["theta_level_se"], float),
                   separation.band_edge_hz + separation.band_taper_hz, translation,
                   None if cov is None else np.asarray(cov, float),
                   MouthpieceNoise.of(m))  # fmt: skip


__all__ = ["LEVEL_KEYS", "NOISE_KEYS", "FrontEnd", "MouthpieceNoise"]
