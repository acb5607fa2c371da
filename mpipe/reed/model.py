"""Time-domain clarinet model: lumped reed coupled to the bore's reflection function.

The explicit scheme of the paper's Appendix A with its signs restored (physics.md G.2-G.4).
Per sample n -> n+1:

1. reed displacement by centred differences, ``y(n+1) = a1 y(n) + a2 y(n-1) + b1 dp(n)
   + a3 [y(n) - y_c]_+^alpha``;
2. opening ``h = max(y_m - y(n+1), 0)`` and reed flow ``u_r = S (y(n+1) - y(n)) / T``;
3. the bore's history term ``q = sum_{j>=1} h_j p+(n+1-j)``;
4. Bernoulli flow ``u_f`` in closed form from the quadratic of physics.md G.3, with the
   lag-0 tap ``h_0`` folded in exactly (physics.md D.2 step 6):
   ``q' = q / (1 - h_0)`` and ``Z0' = Z0 (1 + h_0) / (1 - h_0)`` replace p- and Z0;
5. ``u = u_f + u_r``, ``p+(n+1) = (q + Z0 u) / (1 - h_0)``, ``p- = p+ - Z0 u``,
   ``p = p+ + p-`` and ``dp(n+1) = p_m(n+1) - p``.

Two implementations run it: one compiled kernel (:func:`mpipe.reed.kernels.run`), and a
plain Python/NumPy loop written from the equations (:func:`mpipe.reed.scheme.run_reference`)
that the tests compare it with. ``method`` picks how step 3 is computed:

``"fast"``
    Exact partitioned convolution: lags 1..B-1 run as a direct sum every sample; lags
    >= B run blockwise in the frequency domain (uniformly partitioned overlap-save with a
    frequency-domain delay line). That works because a block of B outputs only needs p+
    at least B samples old, which is all known when the block starts (physics.md D.4).
    The FFT is a small radix-2 implementation compiled with numba.
``"direct"``
    The same compiled kernel with every lag in the direct sum.
``"numpy"``
    The plain reference loop (slow; for tests on short runs).

:func:`simulate_pressure` runs the same compiled kernel for the pressure only, with the
two-level partition of the inversion (:func:`mpipe.reed.bore_kernel.prepare_lean`).

Where it lives: this module holds the driver (:func:`simulate`, :func:`simulate_pressure`)
and its result types; the compiled kernel is in :mod:`mpipe.reed.kernels` (its FFT in
:mod:`mpipe.reed.block_fft`), the bore's preparation and partitions in
:mod:`mpipe.reed.bore_kernel`, the reed coefficients and the reference in
:mod:`mpipe.reed.scheme`, the forward sensitivities in :mod:`mpipe.reed.sensitivity`, and
the playing frequency in :mod:`mpipe.reed.playing`.

Time axis: output sample ``i`` is the state at ``t[i] = (i + 1) / fs``; ``t = 0`` is the
initial state (rest, or the end of a given history), which is not part of the output.

References
----------
Chatziioannou & van Walstijn 2012, Appendix A, eqs. (A.1)-(A.17); physics.md D.2, D.4, G.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from mpipe.reed.bore_kernel import BoreKernel, Partition, prepare_lean
from mpipe.reed.kernels import run
from mpipe.reed.parameters import ReedParameters, check_stability
from mpipe.reed.scheme import run_reference, scheme_records

log = logging.getLogger(__name__)

METHODS = ("fast", "direct", "numpy")


@dataclass(frozen=True)
class ModelState:
    """State of the model at one instant, to start a run from a known history.

    Attributes
    ----------
    p_plus : ndarray
        Past samples of the forward wave p+ at the entry, oldest first, ending at the
        current instant n; length at least ``len(h)`` (Pa).
    y : float
        Reed displacement at n, m.
    y_prev : float
        Reed displacement at n - 1, m.
    dp : float
        Pressure difference p_m - p at n, Pa.
    """

    p_plus: np.ndarray
    y: float
    y_prev: float
    dp: float


@dataclass(frozen=True)
class Simulation:
    """Output of :func:`simulate`, all signals at the mouthpiece entry.

    Attributes
    ----------
    fs : float
        Sample rate, Hz.
    t : ndarray
        Time of each sample, s; ``t[i] = (i + 1) / fs`` after the initial state.
    p : ndarray
        Mouthpiece pressure, Pa.
    u : ndarray
        Volume flow into the bore, m^3/s.
    u_f : ndarray
        Bernoulli flow through the reed channel, m^3/s.
    u_r : ndarray
        Reed-induced flow S dy/dt, m^3/s.
    y : ndarray
        Reed-tip displacement, positive towards closing, m.
    h : ndarray
        Reed opening max(y_m - y, 0), m.
    p_plus, p_minus : ndarray
        Forward and backward pressure waves, Pa.
    reed : ReedParameters
        Parameters used.
    mouth_pressure : ndarray
        Mouth pressure used at each sample (onset and noise included), Pa.
    final_state : ModelState
        State after the last sample, to continue the run.
    method : str
        Kernel used.
    """

    fs: float
    t: np.ndarray
    p: np.ndarray
    u: np.ndarray
    u_f: np.ndarray
    u_r: np.ndarray
    y: np.ndarray
    h: np.ndarray
    p_plus: np.ndarray
    p_minus: np.ndarray
    reed: ReedParameters
    mouth_pressure: np.ndarray
    final_state: ModelState
    method: str


def state_from_signals(
    p: np.ndarray, u: np.ndarray, z0: float, n_taps: int, y: float, y_prev: float, dp: float
) -> ModelState:
    """Model state from a measured or target history of pressure and flow.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure history, Pa, oldest first, ending at the current instant.
    u : ndarray
        Volume flow into the bore at the same instants, m^3/s.
    z0 : float
        Real characteristic impedance of the entry, Pa s/m^3.
    n_taps : int
        Length of the reflection function; at least this many samples are needed.
    y, y_prev : float
        Reed displacement at the current and the previous instant, m.
    dp : float
        Pressure difference p_m - p at the current instant, Pa.

    Returns
    -------
    ModelState
        With ``p_plus = (p + Z0 u) / 2`` over the last ``n_taps`` samples.

    Raises
    ------
    ValueError
        When the histories differ in length or are shorter than ``n_taps``.

    References
    ----------
    physics.md 0 (p = p+ + p-, Z0 u = p+ - p-).
    """
    p = np.asarray(p, dtype=float)
    u = np.asarray(u, dtype=float)
    if p.shape != u.shape or p.ndim != 1:
        raise ValueError(f"p and u: expected 1-D arrays of one length, got {p.shape}, {u.shape}")
    if p.size < n_taps:
        raise ValueError(f"p, u: need at least n_taps = {n_taps} samples of history, got {p.size}")
    p_plus = 0.5 * (p[-n_taps:] + z0 * u[-n_taps:])
    return ModelState(p_plus=p_plus, y=float(y), y_prev=float(y_prev), dp=float(dp))


def mouth_pressure_series(
    reed: ReedParameters,
    n_samples: int,
    fs: float,
    mouth_pressure: np.ndarray | float | None = None,
    onset_s: float = 0.0,
    noise_std_pa: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """Mouth pressure at each output sample, Pa.

    Parameters
    ----------
    reed : ReedParameters
        Supplies the constant p_m when ``mouth_pressure`` is None.
    n_samples : int
        Number of samples.
    fs : float
        Sample rate, Hz.
    mouth_pressure : float or ndarray, optional
        Constant mouth pressure (Pa), or one value per output sample (Pa).
    onset_s : float
        Duration of a raised-cosine rise from 0, s (0: a step).
    noise_std_pa : float
        Standard deviation of white Gaussian breath noise added to the mouth pressure, Pa;
        shaped by the onset like the pressure itself.
    seed : int
        Seed of the noise generator.

    Returns
    -------
    ndarray
        Length ``n_samples``; sample i at t = (i + 1) / fs.
    """
    if mouth_pressure is None:
        pm = np.full(n_samples, reed.p_m)
    elif np.ndim(mouth_pressure) == 0:
        pm = np.full(n_samples, float(mouth_pressure))
    else:
        pm = np.array(mouth_pressure, dtype=float)
        if pm.shape != (n_samples,):
            raise ValueError(
                f"mouth_pressure: expected {n_samples} samples (one per output sample), "
                f"got shape {pm.shape}"
            )
    if not np.all(np.isfinite(pm)):
        raise ValueError("mouth_pressure: contains non-finite values")
    if onset_s < 0 or noise_std_pa < 0:
        raise ValueError(f"onset_s and noise_std_pa must be >= 0, got {onset_s}, {noise_std_pa}")
    env = np.ones(n_samples)
    if onset_s > 0:
        t = np.arange(1, n_samples + 1) / fs
        rising = t < onset_s
        env[rising] = 0.5 * (1 - np.cos(np.pi * t[rising] / onset_s))
    if noise_std_pa > 0:
        rng = np.random.default_rng(seed)
        pm = pm + noise_std_pa * rng.standard_normal(n_samples)
    return pm * env


def simulate(
    reed: ReedParameters,
    kernel: BoreKernel,
    n_samples: int,
    *,
    mouth_pressure: np.ndarray | float | None = None,
    onset_s: float = 0.0,
    noise_std_pa: float = 0.0,
    seed: int = 0,
    method: str = "fast",
    state: ModelState | None = None,
) -> Simulation:
    """Simulate the clarinet: reed model coupled to the bore through its reflection function.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters (SI units).
    kernel : BoreKernel
        Prepared bore, from :func:`prepare_bore`; fixes the sample rate.
    n_samples : int
        Number of samples to compute.
    mouth_pressure : float or ndarray, optional
        Constant mouth pressure in Pa or one value per output sample (Pa); default
        ``reed.p_m``.
    onset_s : float
        Raised-cosine rise time of the mouth pressure, s.
    noise_std_pa : float
        Standard deviation of white breath noise added to the mouth pressure, Pa.
    seed : int
        Seed of the breath noise.
    method : {"fast", "direct", "numpy"}
        Convolution kernel: partitioned FFT (default), direct (compiled), or the plain
        NumPy reference (slow; for tests on short runs).
    state : ModelState, optional
        Start from this history instead of from rest. From rest means y = y_prev = 0,
        p+ = 0 and dp = the mouth pressure at t = 0 (0 with an onset).

    Returns
    -------
    Simulation

    Raises
    ------
    ValueError
        For an unknown method, a too-short state history, bad mouth pressure, or a time
        step that violates the stability bound of the reed update.

    Notes
    -----
    The run is not stopped when it diverges; a diverging run (possible with contact
    stiffness too high for the time step, see :func:`mpipe.reed.parameters.check_stability`) gives
    non-finite samples and a warning in the log.

    References
    ----------
    Chatziioannou & van Walstijn 2012, Appendix A, eqs. (A.1)-(A.17); physics.md G.2-G.4,
    D.2 step 6.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    n_samples = check_length(n_samples)
    fs = kernel.fs
    check_stability(reed, fs)
    pm = mouth_pressure_series(reed, n_samples, fs, mouth_pressure, onset_s, noise_std_pa, seed)
    n_taps = kernel.n_taps
    part = kernel.partition("direct" if method == "numpy" else method)
    n0 = part.n0
    x = np.zeros(n0 + n_samples)
    if state is None:
        # from rest; dp(0) is the mouth pressure at t = 0, which an onset makes 0
        start = (0.0, 0.0, 0.0 if onset_s > 0 else float(pm[0]))
    else:
        start = load_history(x, n0, n_taps, state)
    if method == "numpy":
        out, end = run_reference(x, n0, kernel.h, kernel.z0, kernel.rho, reed, fs, pm, start)
    else:
        out, end = _run_full(x, part, kernel, reed, pm, start)
    if not np.isfinite(out["p"][-1]):
        # debug, not warning: an optimiser meets diverging candidates routinely
        log.debug("simulation diverged (non-finite pressure); check the reed parameters")
    return Simulation(
        fs=fs,
        t=np.arange(1, n_samples + 1) / fs,
        p=out["p"],
        u=out["u"],
        u_f=out["u_f"],
        u_r=out["u_r"],
        y=out["y"],
        h=out["h"],
        p_plus=x[n0:],
        p_minus=out["p_minus"],
        reed=reed,
        mouth_pressure=pm,
        final_state=ModelState(x[-n_taps:].copy(), *end),
        method=method,
    )


def check_length(n_samples: int) -> int:
    """``n_samples`` as an int, at least 1."""
    n_samples = int(n_samples)
    if n_samples < 1:
        raise ValueError(f"n_samples: expected at least 1, got {n_samples}")
    return n_samples


def load_history(x: np.ndarray, n0: int, n_taps: int, state: ModelState) -> tuple:
    """Copy the state's p+ history into ``x[:n0]``; return its (y, y_prev, dp)."""
    hist = np.asarray(state.p_plus, dtype=float)
    if hist.ndim != 1 or hist.size < n_taps:
        raise ValueError(
            f"state.p_plus: expected at least len(h) = {n_taps} past samples, got {hist.size}"
        )
    x[n0 - (n_taps - 1) : n0] = hist[-(n_taps - 1) :]
    return float(state.y), float(state.y_prev), float(state.dp)


def _run_full(
    x: np.ndarray, part: Partition, kernel: BoreKernel, reed: ReedParameters, pm, start: tuple
) -> tuple[dict, tuple]:
    """Every output of the compiled kernel :func:`mpipe.reed.kernels.run` and its end state."""
    n = pm.size
    model = scheme_records(reed, kernel.fs, part.h0, kernel.z0, kernel.rho)
    out = {k: np.empty(n) for k in ("p", "u", "u_f", "u_r", "y", "h", "p_minus")}
    full = tuple(out[k] for k in ("u", "u_f", "u_r", "y", "h", "p_minus"))
    end = run(x, part.n0, model, part.conv(x, n), start, pm, None, out["p"], full, None)
    return out, end


def simulate_pressure(
    reed: ReedParameters,
    kernel: BoreKernel,
    n_samples: int,
    *,
    state: ModelState | None = None,
    lean: Partition | None = None,
) -> np.ndarray:
    """Mouthpiece pressure of :func:`simulate` at constant mouth pressure, by the lean kernel.

    The same scheme as ``simulate(..., method="fast")`` with ``mouth_pressure = reed.p_m``
    and no onset, but only the pressure is computed and kept, and the reflection function
    is split over two delay-line levels (:func:`prepare_lean`); this is the kernel the
    inversion runs (:mod:`mpipe.inversion.fit.fastpath`). Agrees with :func:`simulate` to
    rounding.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters (SI units).
    kernel : BoreKernel
        Prepared bore.
    n_samples : int
        Number of samples.
    state : ModelState, optional
        Start from this history instead of from rest.
    lean : Partition, optional
        The partition to use (default: :func:`prepare_lean` of ``kernel``).

    Returns
    -------
    ndarray
        Pressure, Pa; sample i at t = (i + 1) / fs, as :attr:`Simulation.p`.

    Raises
    ------
    ValueError
        As :func:`simulate`.
    """
    n_samples = check_length(n_samples)
    check_stability(reed, kernel.fs)
    lean = prepare_lean(kernel) if lean is None else lean
    n0 = lean.n0
    x = np.zeros(n0 + n_samples)
    if state is None:
        y, y_prev, dp = 0.0, 0.0, float(reed.p_m)
    else:
        y, y_prev, dp = load_history(x, n0, kernel.n_taps, state)
    out = np.empty(n_samples)
    model = scheme_records(reed, kernel.fs, lean.h0, kernel.z0, kernel.rho)
    pm = np.full(n_samples, reed.p_m)
    run(x, n0, model, lean.conv(x, n_samples), (y, y_prev, dp), pm, None, out, None, None)
    return out
