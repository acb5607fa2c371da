"""A bore whose fingering changes during a take: slurs between fingerings.

A virtual player who changes fingering opens or closes tone holes with the fingers; a
hole goes from open to closed over a few milliseconds, and the bore's reflection function
moves from one fingering's to the other's meanwhile. The model
(:func:`mpipe.reed.controls.play`) runs with one reflection function per piece of the take;
:class:`FingeredBore` gives each piece its own:

* between changes, the reflection function of the fingering played, exactly;
* over a change (``Score.finger_s``, 5 ms by default, ending at the next note's start),
  pieces of at most ``step_s`` (1 ms) each take the linear cross-fade
  ``h = (1 - w) h_a + w h_b`` at the piece's mean position ``w`` of the change.

Why a cross-fade of the reflection functions is defensible: the bore is a linear, passive
system at every instant, and a finger's movement (milliseconds) is slower than the model's
sample period and comparable with one round trip of the bore (3-4 ms for a clarinet), so
the system is treated as quasi-static, piece by piece, with the forward wave's history
carried across (:class:`mpipe.reed.model.ModelState`). A cross-fade of the two impulse
responses is not the impulse response of a half-closed hole (the hole's radiation and
series impedance interpolated), but it has the right end points, stays passive (a convex
combination of two passive reflectances has ``|R| <= 1``), and changes the resonances
over the change's duration as a closing hole does; the few milliseconds of a slur are
the transient the pipeline leaves out of its steady windows anyway.

The reflection functions of every fingering are padded with zeros to one length, so that
the history carried from piece to piece fits every kernel.
"""

from __future__ import annotations

import functools
import types
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mpipe.reed.bore_kernel import BoreKernel, prepare_bore

#: Longest piece of a fingering change over which one cross-faded kernel is held, s.
STEP_S = 1e-3


@dataclass(frozen=True, eq=False)
class FingeredBore:
    """The kernels of a take's fingerings and which one plays at each sample.

    Attributes
    ----------
    kernels : tuple of BoreKernel
        One per fingering (same sample rate, same number of taps).
    source, target : ndarray of int
        Per model sample, the fingering left and the fingering reached (indices into
        ``kernels``; equal outside a change).
    weight : ndarray
        Per model sample, the share of ``target`` (0 to 1).
    step_s : float
        Longest piece of a change held with one cross-faded kernel, s.
    """

    kernels: tuple[BoreKernel, ...]
    source: np.ndarray
    target: np.ndarray
    weight: np.ndarray
    step_s: float = STEP_S

    def __post_init__(self) -> None:
        taps = {k.n_taps for k in self.kernels}
        rates = {k.fs for k in self.kernels}
        if len(taps) != 1 or len(rates) != 1:
            raise ValueError("fingered bore: expected kernels of one length and one rate")
        for name in ("source", "target"):
            values = getattr(self, name)
            if np.any(values < 0) or np.any(values >= len(self.kernels)):
                raise ValueError(f"fingered bore: {name} outside 0..{len(self.kernels) - 1}")

    @property
    def fs(self) -> float:
        """Sample rate, Hz."""
        return float(self.kernels[0].fs)

    def cuts(self, n: int) -> list[int]:
        """Samples where a piece must start: each change's ends, every ``step_s`` within."""
        w = np.asarray(self.weight[:n], dtype=float)
        moving = (w > 0) & (w < 1) & (self.source[:n] != self.target[:n])
        edges = {0, n}
        settled = np.where(w >= 1, self.target[:n], self.source[:n])
        edges.update(int(c) for c in np.flatnonzero(np.diff(settled) != 0) + 1)
        step = max(int(round(self.step_s * self.fs)), 1)
        runs = np.flatnonzero(np.diff(np.r_[False, moving, False].astype(int)))
        for a, b in zip(runs[::2], runs[1::2], strict=True):
            edges.update(range(int(a), int(b), step))
            edges.add(int(b))
        return sorted(e for e in edges if 0 <= e <= n)

    def kernel(self, start: int, stop: int) -> BoreKernel:
        """The kernel of samples ``[start, stop)``: a fingering's, or a cross-fade of two."""
        i, j = int(self.source[start]), int(self.target[start])
        w = float(np.mean(self.weight[start:stop]))
        if i == j or w <= 1e-9:
            return self.kernels[i]
        if w >= 1 - 1e-9:
            return self.kernels[j]
        return self._blend(i, j, round(w, 3))

    @functools.lru_cache(maxsize=64)  # noqa: B019 - a few weights per change, one object per take
    def _blend(self, i: int, j: int, w: float) -> BoreKernel:
        a, b = self.kernels[i], self.kernels[j]
        rf = types.SimpleNamespace(h=(1.0 - w) * a.h + w * b.h, fs=a.fs, z0=a.z0)
        return prepare_bore(rf, types.SimpleNamespace(rho=a.rho), a.head_taps)


def padded(kernels: Sequence[BoreKernel]) -> tuple[BoreKernel, ...]:
    """The kernels with their reflection functions zero-padded to the longest one's taps."""
    n = max(k.n_taps for k in kernels)
    out = []
    for k in kernels:
        if k.n_taps == n:
            out.append(k)
            continue
        h = np.zeros(n)
        h[: k.n_taps] = k.h
        rf = types.SimpleNamespace(h=h, fs=k.fs, z0=k.z0)
        out.append(prepare_bore(rf, types.SimpleNamespace(rho=k.rho), k.head_taps))
    return tuple(out)


def fingered_bore(
    kernels: Sequence[BoreKernel],
    starts_s: Sequence[float],
    indices: Sequence[int],
    finger_s: float,
    n: int,
) -> FingeredBore:
    """The fingered bore of a score: each note's fingering, changed over ``finger_s``.

    Parameters
    ----------
    kernels : sequence of BoreKernel
        One per fingering (padded here to one length).
    starts_s : sequence of float
        Start of each note, s.
    indices : sequence of int
        Each note's fingering, an index into ``kernels``.
    finger_s : float
        Duration of a change, s, ending at the note's start.
    n : int
        Number of model samples (sample i at ``t = (i + 1) / fs``).

    Returns
    -------
    FingeredBore
    """
    kernels = padded(kernels)
    t = np.arange(1, n + 1) / kernels[0].fs
    source = np.full(n, int(indices[0]))
    target = source.copy()
    weight = np.zeros(n)
    for t0, prev, new in zip(starts_s[1:], indices[:-1], indices[1:], strict=True):
        if new == prev:
            continue
        a = t0 - finger_s
        after = t >= a
        w = np.clip((t - a) / finger_s, 0.0, 1.0) if finger_s > 0 else (t >= t0).astype(float)
        done = t >= t0
        source[after], target[after], weight[after] = prev, new, w[after]
        source[done], weight[done] = new, 0.0
    return FingeredBore(kernels, source, target, weight)


__all__ = ["STEP_S", "FingeredBore", "fingered_bore", "padded"]
