"""Least-squares fits of a constant and harmonics on short frames, many frames at once.

The fit of an n-sample frame x at the fundamental ``w`` (rad per sample) onto a constant and
the harmonics k = 1..K is the projection onto their span. The span is written here on the
frame's centred time ``s = t - (n - 1) / 2``: the columns ``cos(k w s)`` (k = 0..K, the
constant first) are even in s and ``sin(k w s)`` odd, so their cross products sum to zero
and the Gram matrix splits into an even block (K + 1 square) and an odd one (K square), each
in closed form from the symmetric Dirichlet kernel ``D(v) = sum_s cos(v s) = sin(n v / 2) /
sin(v / 2)`` (:func:`centred_gram`). The span, so the fit and its power, is that of the
columns ``[1, cos(k w t), sin(k w t)]`` on the frame's own time (a shift turns each
harmonic's cosine and sine into each other); the factorisation costs a quarter.

``H^T x`` is the DFT of x at the harmonics (:func:`harmonic_dft`). Written out it costs
``n K`` complex exponentials; splitting the time ``t = a B + b`` (``B ~ sqrt(n)``) factors
each one, ``exp(i k w t) = exp(i k w B a) exp(i k w b)``, so the sum over t is a matrix
product of the frame (reshaped A x B) with the B factors, weighted by the A factors:
``K (A + B)`` exponentials, and those come from :func:`unit_powers` (two tables of about
``sqrt(K B)`` exponentials). Every value is a product of correctly rounded
exponentials: a few eps, where the powers of one exponential (``z^k``, the recursion this
replaces) lose about k eps.

All functions take ``w`` of any shape (one fundamental per frame, or a grid of candidate
fundamentals) and broadcast it against the frames' leading axes.

References
----------
G. H. Golub, C. F. Van Loan, *Matrix Computations*, 4th ed., section 5.3 (the normal
equations, well conditioned here: the design is far from rank deficient while every
harmonic stays below Nyquist).
"""

from __future__ import annotations

import math

import numpy as np


def unit_powers(w: np.ndarray | float, m: np.ndarray) -> np.ndarray:
    """``exp(i w m)`` for integers ``m >= 0``, shape ``w.shape + m.shape``.

    Parameters
    ----------
    w : ndarray or float
        Angle per step, rad.
    m : ndarray
        Non-negative integers, any shape.

    Returns
    -------
    ndarray
        Complex unit numbers, each the product of two correctly rounded exponentials
        (``exp(i w s q) exp(i w r)``, ``m = s q + r``) from two tables of about
        ``sqrt(max m)`` computed.
    """
    m = np.asarray(m, dtype=int)
    w = np.asarray(w, dtype=float)[..., None]
    top = int(m.max()) if m.size else 0
    step = math.isqrt(top) + 1
    coarse = np.exp(1j * (w * step) * np.arange(top // step + 1))
    fine = np.exp(1j * w * np.arange(step))
    return np.take(coarse, m // step, axis=-1) * np.take(fine, m % step, axis=-1)


def _blocks(n: int) -> tuple[int, int]:
    """Rows and columns (A, B) of an n-sample frame reshaped to ``t = a B + b``."""
    b = math.isqrt(max(n - 1, 0)) + 1
    return -(-n // b), b


def harmonic_factors(
    w: np.ndarray | float, orders: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """The two factors of ``exp(i k w t)``, ``t = a B + b`` (:func:`_blocks`), time first.

    Parameters
    ----------
    w : ndarray or float
        Fundamental, rad per sample.
    orders : ndarray
        Integer multiples k of ``w`` (>= 0), shape (K,).
    n : int
        Samples of the frame.

    Returns
    -------
    coarse : ndarray
        ``exp(i k w B a)``, shape ``w.shape + (A, K)``.
    fine : ndarray
        ``exp(i k w b)``, shape ``w.shape + (B, K)``.
    """
    orders = np.asarray(orders, dtype=int)
    a, b = _blocks(n)
    w = np.asarray(w, dtype=float)
    coarse = unit_powers(w * b, np.arange(a)[:, None] * orders)
    fine = unit_powers(w, np.arange(b)[:, None] * orders)
    return coarse, fine


def harmonic_dft(x: np.ndarray, w: np.ndarray | float, orders: np.ndarray) -> np.ndarray:
    """``sum_t x_t exp(i k w t)`` for each order k: the frames' DFT at the harmonics.

    Parameters
    ----------
    x : ndarray
        Real frames, shape ``(..., n)``, any unit.
    w : ndarray or float
        Fundamental, rad per sample; its shape broadcasts against ``x.shape[:-1]``.
    orders : ndarray
        Integer multiples k of ``w`` (>= 0), shape (K,).

    Returns
    -------
    ndarray
        Complex, shape ``broadcast(x.shape[:-1], w.shape) + (K,)``, x's unit.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    a, b = _blocks(n)
    padded = np.zeros((*x.shape[:-1], a * b))
    padded[..., :n] = x
    coarse, fine = harmonic_factors(w, orders, n)
    # the sum over b: (..., A, B) @ (..., B, K), a real product on the factors' real and
    # imaginary parts side by side (x is real); then the sum over a with its factor
    partial = (padded.reshape(*x.shape[:-1], a, b) @ fine.view(float)).view(complex)
    return np.sum(coarse * partial, axis=-2)


def harmonic_synthesis(
    amplitude: np.ndarray, w: np.ndarray | float, orders: np.ndarray, n: int
) -> np.ndarray:
    """``Re sum_k amplitude_k exp(i k w t)`` for t = 0..n-1: the lines written out.

    Parameters
    ----------
    amplitude : ndarray
        Complex amplitudes, shape ``(..., K)``, any unit.
    w : ndarray or float
        Fundamental, rad per sample; broadcasts against ``amplitude.shape[:-1]``.
    orders : ndarray
        Integer multiples k of ``w``, shape (K,).
    n : int
        Samples.

    Returns
    -------
    ndarray
        Real, shape ``(..., n)``, amplitude's unit.
    """
    coarse, fine = harmonic_factors(w, orders, n)
    weighted = np.asarray(amplitude)[..., None, :] * coarse  # (..., A, K)
    # Re(sum_k p_k f_k) = sum_k (Re p Re f - Im p Im f): conj(p) and f side by side, real
    lines = np.ascontiguousarray(np.conj(weighted)).view(float) @ np.swapaxes(
        fine.view(float), -1, -2
    )
    return lines.reshape(*lines.shape[:-2], -1)[..., :n]


def symmetric_dirichlet(v: np.ndarray, n: int) -> np.ndarray:
    """``sum_s cos(v s)`` over the centred time ``s = t - (n - 1) / 2``, t < n.

    ``sin(n v / 2) / sin(v / 2)``; at the multiples of 2 pi its limit ``n cos(n v / 2) /
    cos(v / 2)`` (n at 0). Real, dimensionless.
    """
    half = 0.5 * np.asarray(v, dtype=float)
    s = np.sin(half)
    tiny = np.abs(s) < 1e-12
    limit = n * np.cos(n * half) / np.where(tiny, np.cos(half), 1.0)
    return np.where(tiny, limit, np.sin(n * half) / np.where(tiny, 1.0, s))


def centred_gram(n: int, w: np.ndarray | float, harmonics: int) -> tuple[np.ndarray, np.ndarray]:
    """The two blocks of the Gram matrix of the centred design (module docstring).

    Parameters
    ----------
    n : int
        Samples of the frame.
    w : ndarray or float
        Fundamental, rad per sample.
    harmonics : int
        K.

    Returns
    -------
    even : ndarray
        ``sum_s cos(k w s) cos(l w s)``, k, l = 0..K: shape ``w.shape + (K + 1, K + 1)``.
    odd : ndarray
        ``sum_s sin(k w s) sin(l w s)``, k, l = 1..K: shape ``w.shape + (K, K)``.
        Both dimensionless: ``(D((k - l) w) +- D((k + l) w)) / 2``.
    """
    w = np.asarray(w, dtype=float)
    d = symmetric_dirichlet(w[..., None] * np.arange(2 * harmonics + 1), n)
    k = np.arange(harmonics + 1)
    minus = np.take(d, np.abs(k[:, None] - k), axis=-1)  # D((k - l) w)
    plus = np.take(d, k[:, None] + k, axis=-1)  # D((k + l) w)
    return 0.5 * (minus + plus), 0.5 * (minus[..., 1:, 1:] - plus[..., 1:, 1:])


def centred_projection(
    x: np.ndarray, w: np.ndarray | float, harmonics: int
) -> tuple[np.ndarray, np.ndarray]:
    """``sum_s x cos(k w s)`` (k = 0..K) and ``sum_s x sin(k w s)`` (k = 1..K), x's unit.

    From the DFT at the harmonics turned to the centred time: ``exp(-i k w (n - 1) / 2)
    sum_t x_t exp(i k w t)``. Shapes ``broadcast(x.shape[:-1], w.shape) + (K + 1,)`` and
    ``(K,)``.
    """
    n = np.shape(x)[-1]
    k = np.arange(harmonics + 1)
    w = np.asarray(w, dtype=float)
    turned = harmonic_dft(x, w, k) * np.exp(-0.5j * (n - 1) * w[..., None] * k)
    return turned.real, turned.imag[..., 1:]


def amplitudes(
    even: np.ndarray, odd: np.ndarray, w: np.ndarray | float, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """The fit ``c + Re sum_k a_k exp(i k w t)`` on the frame's own time from its coefficients.

    Parameters
    ----------
    even, odd : ndarray
        Coefficients of ``cos(k w s)`` (k = 0..K) and ``sin(k w s)`` (k = 1..K), shapes
        ``(..., K + 1)`` and ``(..., K)``, the signal's unit.
    w : ndarray or float
        Fundamental, rad per sample; broadcasts against the leading axes.
    n : int
        Samples of the frame.

    Returns
    -------
    constant : ndarray
        c, shape ``(...)``.
    lines : ndarray
        Complex a_k, shape ``(..., K)``: ``(even_k - i odd_k) exp(-i k w (n - 1) / 2)``.
    """
    k = np.arange(1, odd.shape[-1] + 1)
    turn = np.exp(-0.5j * (n - 1) * np.asarray(w, dtype=float)[..., None] * k)
    return even[..., 0], (even[..., 1:] - 1j * odd) * turn


def bin_columns(n: int, w: float, harmonics: int) -> tuple[np.ndarray, np.ndarray]:
    """The centred design's DFT at the one-sided bins, up to a phase all columns share.

    ``sum_s cos(k w s) cos(theta_f s)`` (k = 0..K) and ``sum_s sin(k w s) sin(theta_f s)``
    (k = 1..K), ``theta_f = 2 pi f / n``, f = 0..n // 2: shapes (K + 1, n // 2 + 1) and
    (K, n // 2 + 1), dimensionless; the DFT of ``cos(k w s)`` at bin f is
    ``exp(-i theta_f (n - 1) / 2)`` times the first, that of ``sin(k w s)`` ``-i`` times
    that phase times the second.

    Each is ``(D(k w - theta_f) +- D(k w + theta_f)) / 2`` (:func:`symmetric_dirichlet`);
    with ``x = k w / 2`` and ``y = pi f / n`` (so ``sin(n (x +- y)) = (-1)^f sin(n x)``) they
    are ``(-1)^f sin(n x) sin(x) cos(y) / (sin^2 x - sin^2 y)`` and the same with ``cos(x)
    sin(y)``: products of short tables, no sine per entry. Within two bins of a harmonic the
    denominator is a difference of close numbers, and the kernels are taken directly there.
    """
    x = 0.5 * w * np.arange(harmonics + 1)
    y = np.pi * np.arange(n // 2 + 1) / n
    sign = np.where(np.arange(y.size) % 2, -1.0, 1.0)
    den = np.subtract.outer(np.sin(x) ** 2, np.sin(y) ** 2)
    tops = np.sin(n * x)
    # the bins within two of each harmonic (and of DC): the kernels there, directly
    near = np.clip(np.rint(x * n / np.pi).astype(int)[:, None] + np.arange(-2, 3), 0, y.size - 1)
    rows = np.repeat(np.arange(x.size), near.shape[1])
    cols = near.ravel()
    np.put(den.reshape(-1), rows * y.size + cols, 1.0)
    even = np.multiply.outer(tops * np.sin(x), sign * np.cos(y))
    even /= den
    odd = np.multiply.outer(tops[1:] * np.cos(x[1:]), sign * np.sin(y))
    odd /= den[1:]
    d_minus = symmetric_dirichlet(2 * (x[rows] - y[cols]), n)
    d_plus = symmetric_dirichlet(2 * (x[rows] + y[cols]), n)
    even[rows, cols] = 0.5 * (d_minus + d_plus)
    keep = rows > 0
    odd[rows[keep] - 1, cols[keep]] = 0.5 * (d_minus - d_plus)[keep]
    return even, odd


__all__ = [
    "amplitudes",
    "bin_columns",
    "centred_gram",
    "centred_projection",
    "harmonic_dft",
    "harmonic_factors",
    "harmonic_synthesis",
    "symmetric_dirichlet",
    "unit_powers",
]
