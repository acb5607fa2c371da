"""A virtual player's controls over time, and the model played under them.

The compiled model (:func:`mpipe.reed.model.simulate`) takes a mouth pressure per sample but
one set of reed parameters per run. A player also moves the embouchure (the rest opening
y_m, the stiffness k the lip leaves free, ...) and stops the reed with the tongue. This
module plays such a take with the model unchanged:

- **Mouth pressure** p_m(t) goes to the kernel sample by sample, as before.
- **Reed parameters** that vary over time are held constant over short pieces of
  ``chunk_s`` (1 ms by default: 100 samples at 100 kHz, far shorter than a period of the
  reed or of the note), each with the mean of its curve over the piece; the model's state
  (:class:`~mpipe.reed.model.ModelState`: the p+ history, y, y at the previous sample and
  Δp) is carried from one piece to the next. With constant parameters the pieces give the
  signal of one run (identically with the ``"direct"`` kernel, to rounding with the
  partitioned FFT of ``"fast"``); with varying ones the result converges as ``chunk_s``
  shrinks (both tested). Where no reed parameter varies the take is one run.
- **Tonguing**: while the tongue holds the reed shut, y = y_m and no air flows (u = 0), so
  the bore rings as a closed pipe: with u = 0 the model's update gives
  ``p+(n) = sum_{j>=1} h_j p+(n-j) / (1 - h_0)`` and ``p = 2 p+`` (physics.md D.2 step 6
  with Z0 u = 0). At the release the reed starts from rest at y = y_m with
  Δp = p_m - p.

References
----------
Chatziioannou & van Walstijn 2012, Appendix A; physics.md D.2, G.2-G.4.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.fingered_bore import FingeredBore
from mpipe.reed.model import ModelState, mouth_pressure_series, simulate
from mpipe.reed.parameters import ReedParameters

#: Reed fields a control curve may drive (y_c and alpha stay fixed, as in the paper).
CURVE_FIELDS = ("k", "S", "y_m", "lam", "m", "g", "k_c")
#: Default length of the pieces over which varying reed parameters are held, s.
CHUNK_S = 1e-3

Curve = float | np.ndarray | Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class Controls:
    """What a virtual player does over a take, one value per model sample.

    Sample i is at ``t = (i + 1) / fs``, as the model's output (:mod:`mpipe.reed.model`).

    Attributes
    ----------
    fs : float
        Model sample rate, Hz.
    p_m : ndarray
        Mouth pressure, Pa, shape ``(n,)`` (before the onset ramp and the breath noise that
        :func:`play` may add).
    reed : mapping of str to ndarray
        Curves of reed parameters that the player moves, field name (of
        :data:`CURVE_FIELDS`) to shape ``(n,)`` values in the field's unit (k in Pa/m, S in
        m^2, y_m in m, lam in m, m in kg/m^2, g in 1/s, k_c in Pa/m^alpha). Fields not
        named keep the reed's value.
    tongue : tuple of (int, int)
        Sample ranges ``[start, stop)`` during which the tongue holds the reed shut.
    notes : tuple of (float, float)
        Sounding span ``(start, end)`` of each note, s (start: the reed is free and blown;
        end: the mouth pressure is back to zero). Recorded in the truth, not used by the
        model.
    """

    fs: float
    p_m: np.ndarray
    reed: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)
    tongue: tuple[tuple[int, int], ...] = ()
    notes: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        n = self.p_m.shape[0] if np.ndim(self.p_m) == 1 else 0
        if n < 1:
            raise ValueError("p_m: expected a 1-D curve with at least one sample")
        if not np.all(np.isfinite(self.p_m)):
            raise ValueError("p_m: contains non-finite values")
        for name, values in self.reed.items():
            if name not in CURVE_FIELDS:
                raise ValueError(f"{name}: not a reed curve; expected one of {CURVE_FIELDS}")
            if np.shape(values) != (n,) or not np.all(np.isfinite(values)):
                raise ValueError(f"{name}: expected {n} finite values, one per sample")
        for a, b in self.tongue:
            if not 0 <= a < b <= n:
                raise ValueError(f"tongue: sample range [{a}, {b}) outside the take (0..{n})")

    @property
    def n_samples(self) -> int:
        """Number of model samples."""
        return int(self.p_m.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Time of each sample, s."""
        return np.arange(1, self.n_samples + 1) / self.fs


def make_controls(
    fs: float,
    n_samples: int,
    p_m: Curve,
    *,
    tongue: Sequence[tuple[float, float]] = (),
    notes: Sequence[tuple[float, float]] | None = None,
    **reed_curves: Curve,
) -> Controls:
    """Controls from numbers, arrays or functions of time.

    Parameters
    ----------
    fs : float
        Model sample rate, Hz.
    n_samples : int
        Length of the take in samples.
    p_m : float, ndarray or callable
        Mouth pressure, Pa: a constant, one value per sample, or ``f(t)`` with t in s
        (``t = (i + 1) / fs``).
    tongue : sequence of (float, float)
        Time spans ``(start, end)`` in s during which the reed is held shut.
    notes : sequence of (float, float), optional
        Sounding spans of the notes, s; default one note over the whole take.
    **reed_curves : float, ndarray or callable
        Reed parameters that vary (names of :data:`CURVE_FIELDS`), as ``p_m``.

    Returns
    -------
    Controls
    """
    t = np.arange(1, int(n_samples) + 1) / fs

    def sample(curve: Curve) -> np.ndarray:
        if callable(curve):
            return np.asarray(curve(t), dtype=float) * np.ones_like(t)
        if np.ndim(curve) == 0:
            return np.full(t.shape, float(curve))
        return np.asarray(curve, dtype=float)

    # a hold over [a, b) s covers the samples with a <= t < b
    spans = tuple(
        (int(np.searchsorted(t, a - 1e-12)), int(np.searchsorted(t, b - 1e-12))) for a, b in tongue
    )
    return Controls(
        fs=float(fs),
        p_m=sample(p_m),
        reed={name: sample(c) for name, c in reed_curves.items()},
        tongue=tuple((a, b) for a, b in spans if b > a),
        notes=((0.0, t[-1]),) if notes is None else tuple(notes),
    )


def vibrato(t: np.ndarray, rate_hz: float, depth: float, start_s: float = 0.0) -> np.ndarray:
    """Vibrato factor ``1 + depth sin(2 pi rate (t - start))`` from ``start_s`` on, else 1.

    Multiply a mouth-pressure curve by it: ``depth = 0.08`` is a vibrato of ±8 % of p_m.
    """
    t = np.asarray(t, dtype=float)
    phase = 2 * np.pi * rate_hz * (t - start_s)
    return np.where(t >= start_s, 1.0 + depth * np.sin(phase), 1.0)


@dataclass(frozen=True)
class Piece:
    """A stretch of the take played with one set of reed parameters.

    Attributes
    ----------
    start, stop : int
        Sample range ``[start, stop)``.
    reed : ReedParameters
        Parameters used over it (its ``p_m`` is not used: the mouth pressure is per sample).
    tongued : bool
        Reed held shut by the tongue (y = y_m, no flow).
    """

    start: int
    stop: int
    reed: ReedParameters
    tongued: bool


@dataclass(frozen=True, eq=False)
class PlayedRun:
    """The model's output under :class:`Controls`, at the mouthpiece entry.

    Attributes
    ----------
    fs : float
        Sample rate, Hz.
    p, u, u_f, u_r, y, h, p_minus : ndarray
        As :class:`mpipe.reed.model.Simulation`: pressure (Pa), flow into the bore, its
        Bernoulli and reed-induced parts (m^3/s), reed displacement and opening (m),
        backward wave (Pa).
    mouth_pressure : ndarray
        Mouth pressure used at each sample (onset and breath noise included), Pa.
    pieces : tuple of Piece
        The stretches of constant reed parameters, in order.
    final_state : ModelState
        State after the last sample.
    controls : Controls
        What the player did (the curves before the pieces' averaging).
    """

    fs: float
    p: np.ndarray
    u: np.ndarray
    u_f: np.ndarray
    u_r: np.ndarray
    y: np.ndarray
    h: np.ndarray
    p_minus: np.ndarray
    mouth_pressure: np.ndarray
    pieces: tuple[Piece, ...]
    final_state: ModelState
    controls: Controls

    def parameter(self, name: str) -> np.ndarray:
        """The reed parameter ``name`` the model used at each sample (its unit)."""
        out = np.empty(self.p.size)
        for piece in self.pieces:
            out[piece.start : piece.stop] = getattr(piece.reed, name)
        return out

    @property
    def tongued(self) -> np.ndarray:
        """Boolean per sample: the reed held shut by the tongue."""
        out = np.zeros(self.p.size, dtype=bool)
        for piece in self.pieces:
            out[piece.start : piece.stop] = piece.tongued
        return out


def plan_pieces(reed: ReedParameters, controls: Controls, chunk_s: float = CHUNK_S) -> list[Piece]:
    """Cut the take into stretches of constant reed parameters.

    Where a curve varies, the grid of ``chunk_s`` pieces holds each curve's mean over the
    grid cell; tongue holds start and stop pieces at their own samples (a cell cut by
    them keeps its value). Neighbouring pieces with equal parameters are merged, so a take
    whose curves are constant and that is not tongued is one piece.

    Raises
    ------
    ValueError
        For ``chunk_s`` shorter than one sample, or a curve value the reed model rejects
        (the error names the parameter and the time).
    """
    n = controls.n_samples
    step = int(round(chunk_s * controls.fs))
    if step < 1:
        raise ValueError(f"chunk_s: expected at least one sample (1/fs), got {chunk_s:g} s")
    varying = {k: v for k, v in controls.reed.items() if np.any(v != v[0])}
    base = dataclasses.replace(
        reed, **{k: float(v[0]) for k, v in controls.reed.items() if k not in varying}
    )
    cuts = {0, n}
    if varying:
        cuts.update(range(step, n, step))
    for a, b in controls.tongue:
        cuts.update((a, b))
    edges = sorted(cuts)
    held = np.zeros(n, dtype=bool)
    for a, b in controls.tongue:
        held[a:b] = True
    pieces: list[Piece] = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        cell = slice((a // step) * step, min((a // step + 1) * step, n))
        values = {k: _cell_value(v[cell]) for k, v in varying.items()}
        try:
            piece_reed = dataclasses.replace(base, **values) if values else base
        except ValueError as exc:
            raise ValueError(f"at t = {(a + 1) / controls.fs:.4f} s: {exc}") from None
        tongued = bool(held[a])
        last = pieces[-1] if pieces else None
        if last is not None and last.reed == piece_reed and last.tongued == tongued:
            pieces[-1] = Piece(last.start, b, piece_reed, tongued)
        else:
            pieces.append(Piece(a, b, piece_reed, tongued))
    return pieces


def _cell_value(values: np.ndarray) -> float:
    """Mean of a curve over a cell; its exact value where it is constant there."""
    first = float(values[0])
    return first if np.all(values == first) else float(np.mean(values))


def play(
    reed: ReedParameters,
    kernel: BoreKernel,
    controls: Controls,
    *,
    onset_s: float = 0.0,
    noise_std_pa: float = 0.0,
    seed: int = 0,
    chunk_s: float = CHUNK_S,
    method: str = "fast",
    fingered: FingeredBore | None = None,
) -> PlayedRun:
    """Play the model on the bore under time-varying controls, from rest.

    Parameters
    ----------
    reed : ReedParameters
        Reed parameters; those without a curve in ``controls`` stay at these values.
    kernel : BoreKernel
        Prepared bore (fixes the sample rate, which must equal ``controls.fs``).
    controls : Controls
        Mouth pressure, reed curves and tongue holds.
    onset_s : float
        Raised-cosine rise of the whole mouth-pressure curve from 0, s (as
        :func:`mpipe.reed.model.simulate`).
    noise_std_pa : float
        Standard deviation of white breath noise on the mouth pressure, Pa.
    seed : int
        Seed of the breath noise.
    chunk_s : float
        Length of the pieces over which varying reed parameters are held, s.
    method : {"fast", "direct"}
        Kernel of :func:`mpipe.reed.model.simulate`.
    fingered : FingeredBore, optional
        A bore whose fingering changes (:mod:`mpipe.reed.fingered_bore`): each piece is
        played on its kernel (``kernel`` then only fixes the rate).

    Returns
    -------
    PlayedRun

    Notes
    -----
    With constant curves, no tongue hold and ``mouth_pressure = controls.p_m`` this is
    exactly ``simulate(reed, kernel, n, mouth_pressure=..., onset_s=..., noise_std_pa=...,
    seed=...)``: the same mouth-pressure series, the same start from rest (Δp = 0 with an
    onset, else the first mouth pressure), one run.
    """
    if abs(kernel.fs - controls.fs) > 1e-9 * kernel.fs:
        raise ValueError(f"controls at {controls.fs:g} Hz, bore kernel at {kernel.fs:g} Hz")
    n = controls.n_samples
    pm = mouth_pressure_series(reed, n, kernel.fs, controls.p_m, onset_s, noise_std_pa, seed)
    pieces = plan_pieces(reed, controls, chunk_s)
    if fingered is not None:
        pieces = _cut(pieces, fingered.cuts(n))
    taps = kernel.n_taps if fingered is None else fingered.kernels[0].n_taps
    state = ModelState(np.zeros(taps), 0.0, 0.0, 0.0 if onset_s > 0 else float(pm[0]))
    names = ("p", "u", "u_f", "u_r", "y", "h", "p_minus")
    out = {k: np.empty(n) for k in names}
    for piece in pieces:
        span = slice(piece.start, piece.stop)
        bore = kernel if fingered is None else fingered.kernel(piece.start, piece.stop)
        if piece.tongued:
            part, state = hold_shut(bore, state, pm[span], piece.reed.y_m)
        else:
            sim = simulate(
                piece.reed,
                bore,
                piece.stop - piece.start,
                mouth_pressure=pm[span],
                method=method,
                state=state,
            )
            part = {k: getattr(sim, k) for k in names}
            state = sim.final_state
        for k in names:
            out[k][span] = part[k]
    return PlayedRun(
        fs=kernel.fs,
        mouth_pressure=pm,
        pieces=tuple(pieces),
        final_state=state,
        controls=controls,
        **out,
    )


def _cut(pieces: list[Piece], cuts: Sequence[int]) -> list[Piece]:
    """The pieces cut again at ``cuts`` (samples), each part keeping its piece's reed."""
    out = []
    for piece in pieces:
        inner = [c for c in cuts if piece.start < c < piece.stop]
        edges = [piece.start, *inner, piece.stop]
        out += [
            Piece(a, b, piece.reed, piece.tongued)
            for a, b in zip(edges[:-1], edges[1:], strict=True)
        ]
    return out


def hold_shut(
    kernel: BoreKernel, state: ModelState, mouth_pressure: np.ndarray, y_m: float
) -> tuple[dict[str, np.ndarray], ModelState]:
    """The bore with its entry shut by the tongue: no flow, the reed at y = y_m.

    Parameters
    ----------
    kernel : BoreKernel
        Prepared bore.
    state : ModelState
        State at the start of the hold.
    mouth_pressure : ndarray
        Mouth pressure over the hold, Pa (it sets Δp at the release).
    y_m : float
        Rest opening, m: the displacement of the shut reed.

    Returns
    -------
    signals : dict of ndarray
        ``p, u, u_f, u_r, y, h, p_minus`` over the hold (u = 0, h = 0, y = y_m).
    state : ModelState
        State at the release: the p+ history, y = y_prev = y_m, Δp = p_m - p.

    References
    ----------
    physics.md D.2 step 6 with u = 0: ``p+(n) (1 - h_0) = sum_{j>=1} h_j p+(n-j)``,
    ``p- = p+``.
    """
    h = kernel.h
    taps = h[1:][::-1].copy()  # lags N-1 .. 1, oldest history first
    nt = taps.size
    n = mouth_pressure.size
    x = np.concatenate([np.asarray(state.p_plus, dtype=float)[-nt:], np.zeros(n)])
    scale = 1.0 / (1.0 - h[0])
    for i in range(n):
        x[nt + i] = float(np.dot(taps, x[i : i + nt])) * scale
    p_plus = x[nt:]
    zero = np.zeros(n)
    signals = {
        "p": 2.0 * p_plus,
        "u": zero,
        "u_f": zero,
        "u_r": zero,
        "y": np.full(n, float(y_m)),
        "h": zero,
        "p_minus": p_plus.copy(),
    }
    end = ModelState(
        x[-kernel.n_taps :].copy(), float(y_m), float(y_m), float(mouth_pressure[-1] - 2 * x[-1])
    )
    return signals, end


def control_curves(run: PlayedRun, step_s: float = CHUNK_S) -> dict[str, np.ndarray]:
    """The truth of a played take on a grid of ``step_s``, compactly (float32).

    Returns
    -------
    dict of ndarray
        ``control_fs`` (Hz, the grid's rate; cell j covers samples ``[j L, (j+1) L)``,
        L = step_s fs), ``control_p_m`` (mean mouth pressure over the cell, Pa), one
        ``control_<field>`` per reed field of :data:`CURVE_FIELDS` (the value the model used
        at the cell's first sample; ``control_lambda`` for lam), ``control_p_M`` (k y_m,
        Pa) and ``control_tongued`` (fraction of the cell the reed is held shut).
    """
    step = max(int(round(step_s * run.fs)), 1)
    n = run.p.size
    starts = np.arange(0, n, step)
    counts = np.diff(np.append(starts, n))

    def mean(values: np.ndarray) -> np.ndarray:
        return (np.add.reduceat(values, starts) / counts).astype(np.float32)

    out: dict[str, np.ndarray] = {"control_fs": np.float64(run.fs / step)}
    out["control_p_m"] = mean(run.mouth_pressure)
    for name in CURVE_FIELDS:
        key = "control_lambda" if name == "lam" else f"control_{name}"
        out[key] = run.parameter(name)[starts].astype(np.float32)
    out["control_p_M"] = (run.parameter("k") * run.parameter("y_m"))[starts].astype(np.float32)
    out["control_tongued"] = mean(run.tongued.astype(float))
    return out


__all__ = [
    "CHUNK_S",
    "CURVE_FIELDS",
    "Controls",
    "Piece",
    "PlayedRun",
    "control_curves",
    "hold_shut",
    "make_controls",
    "plan_pieces",
    "play",
    "vibrato",
]
