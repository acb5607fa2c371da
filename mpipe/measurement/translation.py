"""Translation of p0, u0 from the reference plane to the mouthpiece entry, and the low-pass.

``[P, U] = T(0 -> x_ref) [P0, U0]`` (paper eq. 16, physics.md F.1), where ``T`` is the
chain of transfer matrices of the bore segments between the mouthpiece entry and the
reference plane, evaluated with the air at the effective temperature that the wave
separation found. The elements of ``T`` contain ``exp(+Gamma L)``, a time *advance* of
L/c, and the transform also has long low-frequency tails, so the take is processed in
long FFT blocks (at least 2^17 samples) by overlap-save: each block carries ``pad`` (more
than 2L/c, 50 ms by default) of context on each side, the signal's own samples inside the
take and zeros beyond its ends, as one long zero-padded FFT has them; only the block's
centre is kept. Memory is then bounded by the block, not the take, and every output sample
sees the same context as in one FFT of the whole take (never short circular blocks).
The result is then low-passed with the linear-phase FIR of physics.md F.2, delay
compensated, identical for P and U.

A temperature that drifts over the take is handled without seams: the translation is
computed for a few node temperatures (at most ``temperature_step_c`` apart), each over the
blocks whose temperatures it brackets, and the outputs are interpolated linearly in
temperature sample by sample.
Since the translation is linear in the signals and smooth in temperature, this equals
translating with the local temperature up to a second-order interpolation error.

References
----------
Chatziioannou & van Walstijn 2012, eq. (16) and section 4; physics.md F.1, F.2.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import soundfile as sf
from scipy import fft as sfft

from mpipe.acoustics.bore import transfer_matrix
from mpipe.core.config import between, positive, spec
from mpipe.core.filters import LowPass, apply_lowpass, design_lowpass
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.reconstruction import reference_noise
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.waves import Geometry

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TranslationConfig:
    """Settings of the translation to the mouthpiece and of the final low-pass."""

    lowpass_hz: float = spec(
        "Hz",
        "-6 dB frequency of the linear-phase FIR low-pass (paper: 7.25 kHz)",
        positive,
        default=7250.0,
    )
    transition_hz: float = spec(
        "Hz", "width of the FIR transition band, centred on lowpass_hz", positive, default=1500.0
    )
    stopband_db: float = spec(
        "dB", "stop-band attenuation of the FIR", between(20.0, 150.0), default=60.0
    )
    pad_s: float = spec(
        "s",
        "zero padding at each end of the long FFT; raised to 4 L / c when shorter",
        between(0.0, 10.0),
        default=0.05,
    )
    temperature_step_c: float = spec(
        "degC",
        "largest temperature step between the nodes used for a drifting temperature",
        between(0.01, 10.0),
        default=0.25,
    )

    @property
    def stopband_hz(self) -> float:
        """Where the low-pass's stop band begins, Hz.

        Above it the mouthpiece signals carry nothing of the take (attenuated by
        ``stopband_db``).
        """
        return self.lowpass_hz + 0.5 * self.transition_hz


@dataclass(frozen=True)
class TranslationResult:
    """Signals at the mouthpiece entry and at the reference plane, low-passed.

    Attributes
    ----------
    fs : float
        Sample rate in Hz.
    p : ndarray
        Pressure at the mouthpiece entry, Pa.
    u : ndarray
        Volume flow into the mouthpiece entry, m^3/s (zero mean).
    p0 : ndarray
        Pressure at the reference plane after the same low-pass, Pa.
    u0 : ndarray
        Volume flow at the reference plane after the same low-pass, m^3/s.
    temperature_c : ndarray
        Effective temperature used at each sample, degC.
    lowpass : LowPass
        The FIR applied.
    """

    fs: float
    p: np.ndarray
    u: np.ndarray
    p0: np.ndarray
    u0: np.ndarray
    temperature_c: np.ndarray
    lowpass: LowPass


def reference_to_mouthpiece(
    freqs: np.ndarray, calibration: Calibration, temperature_c: float
) -> np.ndarray:
    """Transfer matrices from the reference plane to the mouthpiece entry.

    Parameters
    ----------
    freqs : ndarray
        Frequencies in Hz, shape ``(n,)``.
    calibration : Calibration
        Bore and reference plane.
    temperature_c : float
        Effective air temperature in degC.

    Returns
    -------
    ndarray
        Shape ``(n, 2, 2)``: ``[P, U] = T @ [P0, U0]`` (physics.md F.1).
    """
    air = calibration.air_properties(temperature_c)
    omega = 2 * np.pi * np.asarray(freqs, dtype=float)
    return transfer_matrix(calibration.bore, omega, air, 0.0, calibration.reference_plane)


def _nodes(temps: np.ndarray, step: float) -> np.ndarray:
    lo, hi = float(np.min(temps)), float(np.max(temps))
    if hi - lo < 1e-9:
        return np.array([lo])
    return np.linspace(lo, hi, int(np.ceil((hi - lo) / step)) + 1)


#: Shortest FFT block of the translation, samples (at least 4 contexts long, so that at
#: most half of each FFT is context), and the context on each side of a block, in pads.
_MIN_BLOCK = 2**17
_CONTEXT = 4


def _block_spectra(p0: np.ndarray, u0: np.ndarray, a: int, b: int, pad: int, nfft: int):
    """Spectra of samples ``a..b`` of p0, u0 with ``pad`` samples of context on each side.

    Outside the take the context is zero, as the one long zero-padded FFT had it.
    """
    buf = np.zeros((2, nfft))
    lo, hi = max(a - pad, 0), min(b + pad, p0.size)
    buf[0, lo - (a - pad) : hi - (a - pad)] = p0[lo:hi]
    buf[1, lo - (a - pad) : hi - (a - pad)] = u0[lo:hi]
    return np.fft.rfft(buf, axis=1)


def _node_weight(temps: np.ndarray, nodes: np.ndarray, k: int) -> np.ndarray:
    """Weight of node ``k`` at each sample: the hat function of linear interpolation."""
    if nodes.size == 1:
        return np.ones(temps.size)
    step = nodes[1] - nodes[0]
    return np.clip(1.0 - np.abs(temps - nodes[k]) / step, 0.0, 1.0)


@dataclass(frozen=True)
class TranslationPlan:
    """What the translation of a take needs, fixed before its first block.

    :meth:`block` translates samples ``a..b`` (before the low-pass) reading only
    ``a - context..b + context`` of p0 and u0: :func:`translate` and
    :func:`mpipe.measurement.translation_stream.translate_to_npz` run the same blocks
    (:meth:`bounds`), so both give the same numbers.

    Attributes
    ----------
    fs : float
        Sample rate, Hz.
    lowpass : LowPass
        The final FIR.
    context : int
        Samples of the take read on each side of a block.
    nfft : int
        FFT length of a block.
    band : ndarray
        The FFT bins below the FIR's stop-band edge (bool).
    nodes : ndarray
        Node temperatures, degC.
    matrices : list of ndarray
        The transfer matrices at each node, shape ``(band bins, 2, 2)``.
    """

    fs: float
    lowpass: LowPass
    context: int
    nfft: int
    band: np.ndarray
    nodes: np.ndarray
    matrices: list

    @classmethod
    def of(
        cls,
        fs: float,
        calibration: Calibration,
        config: TranslationConfig,
        t_min,
        t_max,
        level: int = logging.INFO,
    ) -> TranslationPlan:
        """The plan for a take whose temperature (degC) spans ``t_min..t_max``."""
        lp = design_lowpass(fs, config.lowpass_hz, config.transition_hz, config.stopband_db)
        c_min = calibration.air_properties(t_min).c
        # The transfer matrix advances by L/c and has dispersive tails on both sides; four
        # times the length over c leaves margin beyond the 2L/c of physics.md F.1.
        pad = int(np.ceil(max(config.pad_s, 4 * calibration.reference_plane / c_min) * fs))
        # Each block carries _CONTEXT pads of the take on each side: the transform's
        # low-frequency tails outlast the pad that guards the take's ends.
        context = _CONTEXT * pad
        nfft = sfft.next_fast_len(max(4 * context, _MIN_BLOCK), real=True)
        freqs = np.fft.rfftfreq(nfft, 1 / fs)
        # Above the FIR's stop-band edge the output is discarded by the low-pass anyway, so
        # the transfer matrices are evaluated only below it (the Bessel functions dominate).
        band = freqs <= min(fs / 2, config.lowpass_hz + config.transition_hz)
        nodes = _nodes(np.array([t_min, t_max]), config.temperature_step_c)
        log.log(
            level,
            "translation: %.4f m to the mouthpiece at %s degC, FFT blocks of %d samples",
            calibration.reference_plane,
            f"{nodes[0]:.2f}" if nodes.size == 1 else f"{nodes[0]:.2f}..{nodes[-1]:.2f}",
            nfft,
        )
        matrices = [reference_to_mouthpiece(freqs[band], calibration, float(t)) for t in nodes]
        return cls(float(fs), lp, context, nfft, band, nodes, matrices)

    def bounds(self, n: int):
        """The blocks ``(a, b)`` of a take of ``n`` samples."""
        hop = self.nfft - 2 * self.context
        return [(a, min(a + hop, n)) for a in range(0, n, hop)]

    def block(self, p0, u0, temps: np.ndarray, a: int, b: int):
        """P (Pa) and U (m^3/s) at the mouthpiece for samples ``a..b``, before the low-pass.

        ``p0``, ``u0`` are the whole take's signals (only sliced), ``temps`` the
        temperatures of samples ``a..b`` (degC).
        """
        context, nfft, band = self.context, self.nfft, self.band
        spec_ = _block_spectra(p0, u0, a, b, context, nfft)[:, band]
        p, u = np.zeros(b - a), np.zeros(b - a)
        for k, t in enumerate(self.matrices):
            weight = _node_weight(temps, self.nodes, k)
            if not np.any(weight):
                continue
            out = np.zeros((2, nfft // 2 + 1), dtype=complex)
            out[0, band] = t[:, 0, 0] * spec_[0] + t[:, 0, 1] * spec_[1]
            out[1, band] = t[:, 1, 0] * spec_[0] + t[:, 1, 1] * spec_[1]
            # DC must stay real; U at DC follows from U0 = 0 there (unmeasurable, E.4).
            out[:, 0] = out[:, 0].real
            y = np.fft.irfft(out, nfft, axis=1)[:, context : context + b - a]
            p += weight * y[0]
            u += weight * y[1]
        return p, u


def translate(
    p0: np.ndarray,
    u0: np.ndarray,
    fs: float,
    calibration: Calibration,
    config: TranslationConfig,
    temperature_c: float | np.ndarray | None = None,
    quiet: bool = False,
) -> TranslationResult:
    """Carry p0, u0 from the reference plane to the mouthpiece entry and low-pass them.

    Parameters
    ----------
    p0 : ndarray
        Pressure at the reference plane, Pa, shape ``(n,)``.
    u0 : ndarray
        Volume flow at the reference plane, m^3/s, shape ``(n,)``.
    fs : float
        Sample rate in Hz.
    calibration : Calibration
        Bore geometry, air model and reference plane.
    config : TranslationConfig
        Low-pass and padding settings.
    temperature_c : float or ndarray, optional
        Effective temperature in degC, constant or one value per sample (for example
        :meth:`mpipe.measurement.separation.SeparationResult.temperature_track`); default the
        calibration's.
    quiet : bool
        Log the plan at DEBUG, not INFO: a translation repeated inside another stage (the
        inversion's front-end budget re-translates the take once per front-end quantity)
        does not repeat the stage's line on the console.

    Returns
    -------
    TranslationResult
        P (Pa) and U (m^3/s) at the mouthpiece entry, and p0, u0, all low-passed.

    Raises
    ------
    ValueError
        For signals of different lengths or the low-pass not fitting below Nyquist.

    References
    ----------
    Chatziioannou & van Walstijn 2012, eq. (16); physics.md F.1, F.2.
    """
    p0 = np.asarray(p0, dtype=float)
    u0 = np.asarray(u0, dtype=float)
    if p0.ndim != 1 or p0.shape != u0.shape:
        raise ValueError(f"p0 and u0 must be 1-D of equal length, got {p0.shape}, {u0.shape}")
    n = p0.size
    if temperature_c is None:
        temperature_c = calibration.air.temperature_c
    temps = np.broadcast_to(np.asarray(temperature_c, dtype=float), (n,))
    plan = TranslationPlan.of(fs, calibration, config, float(np.min(temps)), float(np.max(temps)),
                              logging.DEBUG if quiet else logging.INFO)  # fmt: skip
    lp = plan.lowpass
    p, u = np.zeros(n), np.zeros(n)
    for a, b in plan.bounds(n):
        p[a:b], u[a:b] = plan.block(p0, u0, temps[a:b], a, b)
    return TranslationResult(
        fs=float(fs),
        p=apply_lowpass(p, lp),
        u=apply_lowpass(u, lp),
        p0=apply_lowpass(p0, lp),
        u0=apply_lowpass(u0, lp),
        temperature_c=np.array(temps),
        lowpass=lp,
    )


def mouthpiece_noise(
    fs: float,
    calibration: Calibration,
    mic_noise_psd: np.ndarray,
    theta,
    temperature_c: float,
    separation_config=None,
    config: TranslationConfig | None = None,
    df_hz: float = 5.0,
    geometry=None,
) -> dict[str, np.ndarray]:
    """Noise of the mouthpiece pressure and flow, propagated from the microphone noise.

    The white sensor noise of each microphone (one-sided PSD ``mic_noise_psd``, Pa^2/Hz)
    passes through the separation filters (:func:`mpipe.measurement.separation.reference_noise`,
    with the take's median propagation parameters ``theta``), the transfer matrix to the
    mouthpiece and the low-pass::

        S_UU = |H_lp|^2 (|T10|^2 S_p0p0 + |T11|^2 S_u0u0 + 2 Re(T10 conj(T11) S_p0u0))

    and likewise ``S_PP`` with ``T00``, ``T01``; their cross-spectrum ``S_PU = E[P conj(U)]``
    is ``|H_lp|^2 (T00 conj(T10) S_p0p0 + T01 conj(T11) S_u0u0 + T00 conj(T11) S_p0u0 + T01
    conj(T10) conj(S_p0u0))``: the pressure's and the flow's noise are one noise seen twice,
    coherent at low frequency (0.97 at 100 Hz on the shipped instrument, where both come
    mostly from the flow's 1 / (k s) amplification). At low frequency the flow's noise rises as
    ``1 / (k s)``: two waves are told apart by the small phase differences across the
    microphone spacing ``s``.

    Parameters
    ----------
    fs : float
        Sample rate, Hz.
    calibration : Calibration
        Bore, microphones, reference plane.
    mic_noise_psd : ndarray
        One-sided noise PSD per microphone, Pa^2/Hz, shape ``(N,)``.
    theta : mpipe.measurement.separation.Theta
        Propagation parameters of the separation.
    temperature_c : float
        Temperature of the translation, degC.
    separation_config : SeparationConfig, optional
        Band taper and u0 ramp (default settings when omitted).
    config : TranslationConfig, optional
        Low-pass (default settings when omitted).
    df_hz : float
        Frequency step of the grid, Hz.
    geometry : mpipe.measurement.separation.Geometry, optional
        Microphone geometry of the separation (default: the calibration's; pass
        ``SeparationResult.geometry`` to include its position correction).

    Returns
    -------
    dict
        ``u_noise_freq_hz`` (Hz, 0 to fs/2), ``u_noise_psd`` ((m^3/s)^2/Hz, one-sided),
        ``p_noise_psd`` (Pa^2/Hz, one-sided) and ``pu_noise_csd`` (Pa m^3/s / Hz, one-sided,
        complex: ``E[P conj(U)]``) at the mouthpiece entry.
    """
    sep_cfg = SeparationConfig() if separation_config is None else separation_config
    cfg = TranslationConfig() if config is None else config
    freqs = np.arange(0.0, fs / 2 + 0.5 * df_hz, df_hz)
    freqs = freqs[freqs <= fs / 2]
    geo = Geometry.from_calibration(calibration) if geometry is None else geometry
    s_pp0, s_uu0, s_pu0 = reference_noise(freqs, theta, geo, mic_noise_psd, sep_cfg)
    t = reference_to_mouthpiece(np.maximum(freqs, 1e-3), calibration, temperature_c)

    def cross(x, y):
        """E[X conj(Y)] of X = x0 P0 + x1 U0, Y = y0 P0 + y1 U0 (rows of the matrices)."""
        x0, x1, y0, y1 = x[:, 0], x[:, 1], y[:, 0], y[:, 1]
        return (x0 * np.conj(y0) * s_pp0 + x1 * np.conj(y1) * s_uu0
                + x0 * np.conj(y1) * s_pu0 + x1 * np.conj(y0) * np.conj(s_pu0))  # fmt: skip

    lp = design_lowpass(fs, cfg.lowpass_hz, cfg.transition_hz, cfg.stopband_db)
    w = np.exp(-2j * np.pi * np.outer(freqs / fs, np.arange(lp.taps.size)))
    h2 = np.abs(w @ lp.taps) ** 2
    p_row, u_row = t[:, 0, :], t[:, 1, :]
    s_pp = h2 * np.real(cross(p_row, p_row))
    s_uu = h2 * np.real(cross(u_row, u_row))
    s_pu = h2 * cross(p_row, u_row)
    return {
        "u_noise_freq_hz": freqs,
        "u_noise_psd": np.maximum(s_uu, 0.0),
        "p_noise_psd": np.maximum(s_pp, 0.0),
        "pu_noise_csd": s_pu,
    }


#: Full scale of ``mouthpiece.wav``: pressure (channel 1), Pa.
WAV_PRESSURE_SCALE_PA = 1e4
#: Full scale of ``mouthpiece.wav``: volume flow (channel 2), m^3/s.
WAV_FLOW_SCALE_M3_S = 1e-3


def write_mouthpiece_wav(path, p: np.ndarray, u: np.ndarray, fs: float) -> None:
    """Write mouthpiece pressure and flow as a two-channel floating-point WAV file, to listen to.

    Parameters
    ----------
    path : str or Path
        WAV file (not atomic: wrap in :func:`mpipe.core.io.write_atomic`).
    p, u : ndarray
        Pressure (Pa) and volume flow (m^3/s), scaled by ``WAV_PRESSURE_SCALE_PA`` and
        ``WAV_FLOW_SCALE_M3_S`` to full scale.
    fs : float
        Sample rate, Hz.
    """
    with sf.SoundFile(path, "w", int(round(fs)), 2, subtype="FLOAT", format="WAV") as f:
        for a in range(0, p.size, 2**18):  # in blocks: memory does not grow with the take
            block = np.empty((min(2**18, p.size - a), 2), dtype=np.float32)
            block[:, 0] = p[a : a + block.shape[0]] / WAV_PRESSURE_SCALE_PA
            block[:, 1] = u[a : a + block.shape[0]] / WAV_FLOW_SCALE_M3_S
            f.write(block)
